"""Fixtures of the browser tests: one headless Chromium (Debian's, SwiftShader WebGL2) per
session, pages that record console errors, and the demo's 40-light draft build."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.web.harness import CHROMIUM_FLAGS, SCREENSHOTS, chromium_path


@pytest.fixture(scope="session")
def browser():
    from playwright.sync_api import sync_playwright

    executable = chromium_path()  # fails (never skips) when chromium is missing
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=executable, args=CHROMIUM_FLAGS, headless=True)
        yield b
        b.close()


class Page:
    """A Playwright page plus the console errors and page errors it produced."""

    def __init__(self, browser, width=640, height=360, has_touch=False,
                 service_workers="allow"):
        self.context = browser.new_context(viewport={"width": width, "height": height},
                                           has_touch=has_touch, service_workers=service_workers)
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.page.on("console", lambda m: self.errors.append(f"console.{m.type}: {m.text}")
                     if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(f"pageerror: {e}"))

    def open(self, url: str, ready: str = "window.daylit && window.daylit.status.ready",
             timeout_ms: int = 60000):
        self.page.goto(url)
        self.page.wait_for_function(ready, timeout=timeout_ms)
        return self

    def status(self) -> dict:
        return self.page.evaluate("JSON.parse(JSON.stringify(window.daylit.status))")

    def wait(self, expression: str, timeout_ms: int = 30000):
        self.page.wait_for_function(expression, timeout=timeout_ms)

    def screenshot(self, name: str):
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        self.page.screenshot(path=str(SCREENSHOTS / f"{name}.png"))

    def close(self):
        self.context.close()


@pytest.fixture
def new_page(browser):
    pages = []

    def make(width=640, height=360, has_touch=False, service_workers="allow"):
        p = Page(browser, width, height, has_touch, service_workers)
        pages.append(p)
        return p

    yield make
    for p in pages:
        p.close()


@pytest.fixture(scope="session")
def web_build(request):
    """The demo at draft quality with 40 lights (tests/conftest.py bakes it once per session;
    DAYLIT_WEB_BUILD names an existing draft build instead, to iterate quickly)."""
    existing = os.environ.get("DAYLIT_WEB_BUILD")
    if existing:
        return Path(existing)
    return request.getfixturevalue("demo_draft_build")


@pytest.fixture(scope="session")
def reference(web_build):
    from bake.evaluate import Build

    return Build(web_build)


@pytest.fixture(scope="session")
def sun_build(tmp_path_factory):
    """The sun tests' site (tests/web/sunsite.py), baked once per session (draft);
    DAYLIT_SUN_BUILD names an existing bake of it instead, to iterate quickly."""
    from tests.web.sunsite import bake_sun_site

    existing = os.environ.get("DAYLIT_SUN_BUILD")
    if existing:
        return Path(existing)
    return bake_sun_site(tmp_path_factory.mktemp("sunsite"))


@pytest.fixture(scope="session")
def sun_reference(sun_build):
    """The sun site's build reader and its ray-cast casters (bake/sunlight.py, the oracle)."""
    from bake.evaluate import Build
    from bake.sunlight import SunCasters

    build = Build(sun_build)
    casters = SunCasters.from_site_glb(sun_build / build.manifest["model"]["path"])
    return build, casters
