"""Real touch input for the browser tests: CDP ``Input.dispatchTouchEvent``, so the page gets
the touch and pointer events a phone's screen gives (the page's own handlers, the browser's
hit testing and ``touch-action``)."""

from __future__ import annotations


def touch_moves(page, fingers_start, fingers_end, steps: int = 5) -> None:
    """Fingers put down at ``fingers_start`` [(x, y), ...] CSS px, moved in ``steps`` straight
    steps to ``fingers_end`` (same length), then lifted."""
    cdp = page.context.new_cdp_session(page)

    def points(t):
        return [{"x": x0 + t * (x1 - x0), "y": y0 + t * (y1 - y0), "id": i}
                for i, ((x0, y0), (x1, y1)) in enumerate(zip(fingers_start, fingers_end,
                                                             strict=True))]

    cdp.send("Input.dispatchTouchEvent", {"type": "touchStart", "touchPoints": points(0)})
    for step in range(1, steps + 1):
        cdp.send("Input.dispatchTouchEvent",
                 {"type": "touchMove", "touchPoints": points(step / steps)})
    cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})
    cdp.detach()


def touch_drag(page, fingers_start, dx_px: float, dy_px: float, steps: int = 5) -> None:
    """Drag ``fingers_start`` [(x, y), ...] CSS px by (dx, dy) together."""
    touch_moves(page, fingers_start, [(x + dx_px, y + dy_px) for x, y in fingers_start], steps)


def tap(page, x_px: float, y_px: float) -> None:
    """One finger down and up at (x, y) CSS px, not moved."""
    touch_moves(page, [(x_px, y_px)], [(x_px, y_px)], steps=0)
