"""A bare WebGL2 page for evaluating the shipped GLSL chunks in headless Chromium.

The page is served from a made-up origin (``http://daylit.test/``) by Playwright's request
routing: ``/src/...`` is ``web/src``, ``/vendor/three/...`` is three.js as ``daylit serve``
maps it, so the test imports the very modules the client ships. ``window.runFragment``
compiles a GLSL ES 3.00 fragment shader over a full-screen triangle into a float RGBA target
and returns the pixels, row 0 at the bottom (``gl_FragCoord.y = 0.5``).
"""

from __future__ import annotations

import contextlib
import mimetypes

import numpy as np

from tests.web.harness import THREE, WEB

ORIGIN = "http://daylit.test"

PAGE = """<!doctype html><html><head><meta charset="utf-8">
<script type="importmap">{"imports": {"three": "/vendor/three/build/three.module.js",
  "three/addons/": "/vendor/three/examples/jsm/"}}</script>
<script>
// uniforms: {name: {type: '1f' | '2f' | '3fv' | 'tex', value}}; a 'tex' value is
// {width, height, data: RGBA float array}, bound with NEAREST filtering (texelFetch).
window.runFragment = (source, width, height, uniforms) => {
  const canvas = document.createElement('canvas');
  const gl = canvas.getContext('webgl2');
  if (!gl.getExtension('EXT_color_buffer_float')) throw new Error('no EXT_color_buffer_float');
  const compile = (type, text) => {
    const s = gl.createShader(type);
    gl.shaderSource(s, text);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  };
  const program = gl.createProgram();
  gl.attachShader(program, compile(gl.VERTEX_SHADER,
    '#version 300 es\\nin vec2 p;\\nvoid main() { gl_Position = vec4(p, 0.0, 1.0); }'));
  gl.attachShader(program, compile(gl.FRAGMENT_SHADER, source));
  gl.bindAttribLocation(program, 0, 'p');
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) {
    throw new Error(gl.getProgramInfoLog(program));
  }
  gl.useProgram(program);
  let unit = 0;
  for (const [name, { type, value }] of Object.entries(uniforms)) {
    const at = gl.getUniformLocation(program, name);
    if (at === null) throw new Error(`no uniform ${name}`);
    if (type === 'tex') {
      const t = gl.createTexture();
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, value.width, value.height, 0, gl.RGBA,
        gl.FLOAT, new Float32Array(value.data));
      gl.uniform1i(at, unit++);
    } else {
      gl[`uniform${type}`](at, ...(type.endsWith('v') ? [new Float32Array(value)] : value));
    }
  }
  const target = gl.createTexture();
  gl.activeTexture(gl.TEXTURE0 + unit); // a unit no uniform reads
  gl.bindTexture(gl.TEXTURE_2D, target);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, width, height, 0, gl.RGBA, gl.FLOAT, null);
  const fb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, target, 0);
  const buffer = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 3, -1, -1, 3]), gl.STATIC_DRAW);
  gl.enableVertexAttribArray(0);
  gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
  gl.viewport(0, 0, width, height);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
  const out = new Float32Array(4 * width * height);
  gl.readPixels(0, 0, width, height, gl.RGBA, gl.FLOAT, out);
  const error = gl.getError();
  if (error) throw new Error(`WebGL error ${error}`);
  return Array.from(out);
};
</script></head><body></body></html>"""


def _route(route):
    path = route.request.url[len(ORIGIN):].split("?")[0]
    if path in ("/", "/shader.html"):
        return route.fulfill(status=200, content_type="text/html", body=PAGE)
    for prefix, root in (("/vendor/three/", THREE), ("/src/", WEB / "src")):
        if path.startswith(prefix):
            file = (root / path[len(prefix):]).resolve()
            if file.is_relative_to(root.resolve()) and file.is_file():
                kind = "text/javascript" if file.suffix in (".js", ".mjs") else (
                    mimetypes.guess_type(file.name)[0] or "application/octet-stream")
                return route.fulfill(status=200, content_type=kind, body=file.read_bytes())
    return route.fulfill(status=404, body="not found")


@contextlib.contextmanager
def shader_page(browser):
    """A page at the made-up origin with ``runFragment``; yields (page, errors)."""
    context = browser.new_context()
    try:
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.route(f"{ORIGIN}/**", _route)
        page.goto(f"{ORIGIN}/shader.html")
        yield page, errors
    finally:
        context.close()


def pixels(flat: list[float], width: int, height: int) -> np.ndarray:
    """(height, width, 4) float from runFragment's list, row 0 at the bottom."""
    return np.asarray(flat, dtype=np.float64).reshape(height, width, 4)

