"""An emulated WebXR device for the AR tests and benchmark (test-only: never served to
visitors). IWER (npm ``iwer``, pinned in package.json) replaces ``navigator.xr`` in the page
with a Meta Quest 3 in immersive-ar, one eye drawn (stereo off); hit tests go to
:data:`FLOOR_SEM`, a synthetic environment holding one thing, the floor plane y = 0 of the
session's local-floor space. The poses and what the device should see are computed here in
numpy (:func:`pose_m`, :func:`floor_hit_m`, :func:`left_eye_m`, :func:`perspective`), from the
WebXR and IWER definitions, not read from the page.
"""

from __future__ import annotations

import numpy as np

from tests.web.harness import REPO

IWER_JS = REPO / "node_modules" / "iwer" / "build" / "iwer.min.js"
IPD_M = 0.063          # IWER's default inter-pupillary distance
FOVY_RAD = np.pi / 2   # IWER's default vertical field of view

# IWER asks a "synthetic environment module" for hit tests (ray: the space's -z axis, in
# IWER's global space, which is local-floor's). This one is the floor y = 0, nothing else.
FLOOR_SEM = """
class FloorSEM {
  constructor() {
    this.environmentCanvas = document.createElement('canvas');
    this.trackedPlanes = new Set();
    this.trackedMeshes = new Set();
  }
  render() {}
  computeHitTestResults(m) {
    const o = [m[12], m[13], m[14]];
    const d = [-m[8], -m[9], -m[10]];
    if (d[1] > -1e-6) return [];
    const t = -o[1] / d[1];
    const hit = new Float32Array(16);
    hit[0] = 1; hit[5] = 1; hit[10] = 1; hit[15] = 1;
    hit[12] = o[0] + t * d[0]; hit[13] = 0; hit[14] = o[2] + t * d[2];
    return [hit];
  }
}
"""


def init_script() -> str:
    """The page's first script: IWER, the device, the floor. ``window.__xr`` is the device."""
    if not IWER_JS.is_file():
        raise RuntimeError(f"{IWER_JS} is missing: run `make setup` (npm ci installs iwer)")
    return IWER_JS.read_text() + FLOOR_SEM + """
window.__xr = new IWER.XRDevice(IWER.metaQuest3, { stereoEnabled: false });
window.__xr.installRuntime({ forceInstall: true });
window.__xr.installSEM(FloorSEM);
"""


def rotation(yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """(3, 3): yaw about +y, then pitch about the turned +x, then roll about -z (view axis)."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return ry @ rx @ rz


def quaternion(rot: np.ndarray) -> list[float]:
    """[x, y, z, w] of a rotation matrix (3, 3) (trace method; our poses stay far from 180 deg)."""
    w = np.sqrt(max(1e-12, 1 + np.trace(rot))) / 2
    return [(rot[2, 1] - rot[1, 2]) / (4 * w), (rot[0, 2] - rot[2, 0]) / (4 * w),
            (rot[1, 0] - rot[0, 1]) / (4 * w), w]


def pose_m(position_m, rot: np.ndarray) -> np.ndarray:
    """(4, 4) world-from-device, metres."""
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = position_m
    return m


def floor_hit_m(pose: np.ndarray) -> np.ndarray:
    """(3,) where the device's forward ray (-z) meets the floor y = 0, metres."""
    o, d = pose[:3, 3], -pose[:3, 2]
    return o + (-o[1] / d[1]) * d


def left_eye_m(pose: np.ndarray) -> np.ndarray:
    """(4, 4) world-from-left-eye: the device pose offset by half the IPD along its -x."""
    offset = np.eye(4)
    offset[0, 3] = -IPD_M / 2
    return pose @ offset


def perspective(fovy_rad: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4, 4) the OpenGL perspective projection (as gl-matrix writes it)."""
    f = 1 / np.tan(fovy_rad / 2)
    return np.array([[f / aspect, 0, 0, 0], [0, f, 0, 0],
                     [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
                     [0, 0, -1, 0]])


def project_px(points_m: np.ndarray, world_from_eye: np.ndarray, projection: np.ndarray,
               size_px: tuple[int, int]) -> np.ndarray:
    """(n, 2) canvas pixels (x right, y down, from the top left) of world points (n, 3)."""
    h = np.c_[points_m, np.ones(len(points_m))] @ (projection @ np.linalg.inv(world_from_eye)).T
    ndc = h[:, :2] / h[:, 3:4]
    w, hgt = size_px
    return np.c_[(ndc[:, 0] + 1) / 2 * w, (1 - ndc[:, 1]) / 2 * hgt]


def column_major(m: np.ndarray) -> list[float]:
    return np.asarray(m, dtype=float).T.ravel().tolist()


def from_column_major(values) -> np.ndarray:
    return np.asarray(values, dtype=float).reshape(4, 4).T


def camera_access_script(size_px: tuple[int, int], bands) -> str:
    """A stand-in for WebXR raw camera access (IWER has none; Chrome on Android has it since
    107), run after :func:`init_script`: a session that asks for 'camera-access' has it, every
    view has a camera of ``size_px`` (the canvas's: the picture aligned with the view), and
    ``getCameraImage`` gives a texture of a picture of horizontal ``bands`` [(first row from
    the top, (r, g, b) sRGB codes), ...], stored as a GL texture whose first row is the
    picture's bottom (the convention a quad drawn with it shows upright). The GL state the
    upload touches is put back as it was: three.js keeps its own copy of it."""
    w, h = size_px
    fills = "".join(f"c.fillStyle = 'rgb({r},{g},{b})'; c.fillRect(0, {row}, {w}, {h - row});\n"
                    for row, (r, g, b) in bands)
    return f"""
(() => {{
  const picture = document.createElement('canvas');
  picture.width = {w}; picture.height = {h};
  const c = picture.getContext('2d');
  {fills}
  const request = navigator.xr.requestSession.bind(navigator.xr);
  navigator.xr.requestSession = async (mode, init = {{}}) => {{
    const session = await request(mode, init);
    const asked = [...(init.requiredFeatures ?? []), ...(init.optionalFeatures ?? [])];
    if (asked.includes('camera-access')) {{
      const features = [...session.enabledFeatures, 'camera-access'];
      Object.defineProperty(session, 'enabledFeatures', {{ get: () => features }});
    }}
    return session;
  }};
  const camera = {{ width: {w}, height: {h} }};
  const View = window.XRView ?? IWER.XRView;
  Object.defineProperty(View.prototype, 'camera', {{ get: () => camera, configurable: true }});
  let texture = null;
  window.__cameraImages = 0;
  // The binding remembers its context (three.js makes one with the renderer's).
  class Binding extends window.XRWebGLBinding {{
    constructor(session, gl) {{
      super(session, gl);
      this.gl = gl;
    }}
  }}
  window.XRWebGLBinding = Binding;
  Binding.prototype.getCameraImage = function () {{
    window.__cameraImages += 1;
    if (texture) return texture;
    const gl = this.gl;
    const flip = gl.getParameter(gl.UNPACK_FLIP_Y_WEBGL);
    const premultiply = gl.getParameter(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL);
    const bound = gl.getParameter(gl.TEXTURE_BINDING_2D);
    texture = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, texture);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, true);
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, picture);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, flip);
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, premultiply);
    gl.bindTexture(gl.TEXTURE_2D, bound);
    return texture;
  }};
}})();
"""
