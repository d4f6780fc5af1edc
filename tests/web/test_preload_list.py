"""Every module of the page's static import graph is in index.html's modulepreload list.

The list is kept by hand (docs/web.md "Slow links": on a 300 ms link each import found late costs
a round trip); a module added to the client without its line would load late without any error.
The graph is walked here from the files themselves (static ``import ... from '...'`` and
``export ... from '...'``), through the page's import map, into three.js as installed.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import urljoin

ROOT = Path(__file__).resolve().parents[2]
WEB = ROOT / "web"
THREE = ROOT / "node_modules" / "three"
INDEX = WEB / "index.html"
# at the start of a line (module level): `import x from '...'`, `export {...} from '...'`
# (across lines too), `import '...'`
STATIC_IMPORT = re.compile(
    r"""^(?:(?:import|export)\s[^;'"]*?\bfrom\s*|import\s*)['"]([^'"]+)['"]""", re.MULTILINE)


def _file_of(url: str) -> Path:
    """The file a page URL (absolute path, served by daylit) reads."""
    if url.startswith("/vendor/three/"):
        return THREE / url[len("/vendor/three/"):]
    return WEB / url.lstrip("/")


def _resolve(spec: str, base_url: str, imports: dict) -> str:
    if spec in imports:
        return imports[spec]
    for prefix, target in imports.items():
        if prefix.endswith("/") and spec.startswith(prefix):
            return target + spec[len(prefix):]
    return urljoin(base_url, spec)


def test_every_statically_imported_module_is_preloaded():
    html = INDEX.read_text()
    imports = json.loads(re.search(r'<script type="importmap">(.*?)</script>', html,
                                   re.DOTALL).group(1))["imports"]
    preloaded = {urljoin("/", href) for href in
                 re.findall(r'<link rel="modulepreload" href="([^"]+)"', html)}
    entry = urljoin("/", re.search(r'<script type="module" src="([^"]+)"', html).group(1))
    seen, todo = set(), [entry]
    while todo:
        url = todo.pop()
        if url in seen:
            continue
        seen.add(url)
        path = _file_of(url)
        assert path.is_file(), f"{url} is imported but {path} does not exist"
        for spec in STATIC_IMPORT.findall(path.read_text()):
            todo.append(_resolve(spec, url, imports))
    missing = sorted(seen - preloaded - {entry})
    assert not missing, f"imported but not preloaded in web/index.html: {missing}"
    stale = sorted(u for u in preloaded if not _file_of(u).is_file())
    assert not stale, f"preloaded but no such file: {stale}"
    assert len(seen) > 20  # the walk found the graph (app, three.js, loaders)
