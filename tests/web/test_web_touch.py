"""The virtual visit under a phone's fingers (docs/web.md, "The virtual visit"): real touch
events (CDP) on the page as it ships. One finger orbits the site about its centre by 360
degrees per screen height of motion (three.js OrbitControls), never below the ground; two
fingers spread apart zoom in by their spread's ratio; the slow turn by itself stops at the
first touch. The answers are OrbitControls' documented behaviour, computed here from the
finger motion; what is tested is that the page's touches reach it as a phone's would (the
canvas's touch-action, nothing of the HUD in between) and the limits the visit sets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.web.harness import StubServer
from tests.web.kioskref import light_message
from tests.web.touch import touch_drag, touch_moves

pytestmark = [pytest.mark.browser]

SIZE = (390, 700)  # a phone held upright, CSS px
READY = "window.daylit.status.ready"


def settled_orbit(page) -> dict:
    """The orbit once the camera stopped moving (OrbitControls' damping runs on for some
    frames after the fingers lift): the same over three frames the page drew in a row, read
    after the app's own frame callback. Counted in drawn frames, not in time, so a slow
    machine that draws few frames cannot pass off a pose from before the gesture's first
    update as settled."""
    return page.evaluate("""async () => {
      const frame = () => new Promise((resolve) => requestAnimationFrame(resolve));
      const limit = performance.now() + 60000;
      let last = null;
      let same = 0;
      while (performance.now() < limit) {
        await frame();
        const o = window.daylit.debug.orbit();
        const key = o.position.map((v) => v.toFixed(6)).join();
        same = key === last && !o.autoRotate ? same + 1 : 0;
        last = key;
        if (same >= 3) return o;
      }
      throw new Error('the orbit did not settle within 60 s');
    }""")


def spherical(orbit: dict) -> tuple[float, float, float]:
    """(distance m, azimuth deg, polar deg) of the camera about the target, as OrbitControls
    measures them (+y up; azimuth atan2(x, z))."""
    offset = np.subtract(orbit["position"], orbit["target"])
    distance = float(np.linalg.norm(offset))
    return (distance, math.degrees(math.atan2(offset[0], offset[2])),
            math.degrees(math.acos(offset[1] / distance)))


def free_point(page) -> tuple[float, float]:
    """A point of the screen where the canvas itself takes the touch (no HUD element)."""
    point = page.evaluate("""() => {
      for (let y = innerHeight * 0.45; y < innerHeight * 0.9; y += 10) {
        for (let x = innerWidth * 0.3; x < innerWidth * 0.7; x += 10) {
          if (document.elementFromPoint(x, y)?.id === 'view') return [x, y];
        }
      }
      return null;
    }""")
    assert point is not None
    return tuple(point)


def test_visit_orbits_and_zooms_under_two_fingers(new_page, web_build, reference):
    with StubServer(web_build) as server:
        server.push(light_message(reference.light_vector("clear:135,40"), 1), remember=True)
        visit = new_page(*SIZE, has_touch=True).open(server.url + "/?mode=visit&test", READY)
        page = visit.page
        assert page.evaluate("window.daylit.debug.orbit().autoRotate")
        x, y = free_point(page)
        height = page.evaluate("document.getElementById('view').clientHeight")

        # One finger 70 px to the right: the camera goes 70/height of a turn the other way
        # about the target (OrbitControls: rotateLeft(2 pi dx / height)), same distance and
        # height; the turning by itself stops.
        touch_drag(page, [(x - 35, y)], 0, 0, steps=1)  # the first touch stops the auto-turn
        before = settled_orbit(page)
        d0, az0, polar0 = spherical(before)
        touch_drag(page, [(x - 35, y)], 70, 0)
        after = settled_orbit(page)
        d1, az1, polar1 = spherical(after)
        turned = (az1 - az0 + 180) % 360 - 180
        assert turned == pytest.approx(-360 * 70 / height, abs=0.3)
        assert d1 == pytest.approx(d0, rel=1e-4) and polar1 == pytest.approx(polar0, abs=0.05)
        np.testing.assert_allclose(after["target"], before["target"], atol=1e-6)

        # Fingers 60 px apart spread to 120 px, about a fixed midpoint: half the distance,
        # the same direction (a pure zoom: the midpoint does not move, so no pan).
        touch_moves(page, [(x - 30, y), (x + 30, y)], [(x - 60, y), (x + 60, y)], steps=6)
        zoomed = settled_orbit(page)
        d2, az2, polar2 = spherical(zoomed)
        assert d2 == pytest.approx(d1 / 2, rel=0.01)
        assert az2 == pytest.approx(az1, abs=0.05) and polar2 == pytest.approx(polar1, abs=0.05)

        # One finger far up the screen: the camera would go below the horizon; the visit
        # stops it at 0.49 pi from the zenith, above the ground.
        touch_drag(page, [(x, y - 20)], 0, -0.6 * height, steps=8)
        low = settled_orbit(page)
        _, _, polar3 = spherical(low)
        assert polar3 == pytest.approx(0.49 * 180, abs=0.05)
        assert low["position"][1] > low["target"][1]
        assert not visit.errors, visit.errors
