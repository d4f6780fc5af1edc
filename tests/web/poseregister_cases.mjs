// Runs web/src/poseregister.js's registerShift in Node on the cases given as JSON on stdin:
// [{codes (h * w * 3 sRGB codes, rows from the top), w, h, pool [{x, y, albedo}], lit, fovDeg}]
// -> each case's registration {dx, dy, fisher, fisherAtZero, turnDeg}.
// For tests/web/test_phoneestimate_js.py.
import { readFileSync } from 'node:fs';
import { registerShift } from '../../web/src/poseregister.js';

const cases = JSON.parse(readFileSync(0, 'utf8'));
const out = cases.map(({ codes, w, h, pool, lit, fovDeg }) => {
  const rgba = new Uint8ClampedArray(4 * w * h);
  for (let i = 0; i < w * h; i++) {
    rgba.set(codes.slice(3 * i, 3 * i + 3), 4 * i);
    rgba[4 * i + 3] = 255;
  }
  return registerShift(rgba, w, h, pool, lit, fovDeg, { clipCode: 250, darkCode: 3 });
});
process.stdout.write(JSON.stringify(out));
