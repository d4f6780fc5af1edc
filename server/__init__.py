"""The light server: ``daylit serve`` and ``daylit calibrate`` (docs/server.md).

One concept per module:

- ``app``: aiohttp application factory, shared state (``web.AppKey``), supervised background
  tasks, ``/api/status`` and ``/api/sky.jpg``;
- ``routes``: static serving of ``web/``, three.js and the build;
- ``lightstream``: the WebSocket broadcast of light vectors (and kiosk camera frames);
- ``protocol``: the wire format (docs/protocol.md);
- ``pipeline``: newest frame -> measurement -> smoothing -> publish, stale detection;
- ``measure``: fisheye frame -> light vector (Sato Sec. 5), with ``photometry``,
  ``patchmatrix`` and ``binning``; ``temporalfilter``: smoothing and when to send;
- ``fisheye``: the lens model and its rotation to the site frame;
- ``simsky``: the simulated sky with a known answer;
- ``sources``: sim, replay and live camera sources;
- ``sitecamera``: the kiosk's site camera as JPEG frames;
- ``calibrate``: intrinsics from checkerboards, north from the sun;
- ``config``: settings from TOML and flags;
- ``throttledlog``: repeated warnings at most once per interval, with a count;
- ``cli``: the command line.

It learns the dome from the build's ``manifest.json`` and never imports the baker.
"""
