// Runs web/src/lightmath.js's light selection on every case of tests/vectors/light_selection.json
// (r as the light stream carries it: float32) and prints {name: selected lights} as JSON, for
// tests/web/test_selection_js.py to compare with the hand-worked answers.
import { readFileSync } from 'node:fs';
import { selectionWeights, selectLights } from '../../web/src/lightmath.js';

const vectors = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const out = {};
for (const c of vectors.cases) {
  const r = Float32Array.from(c.r.flat());
  out[c.name] = selectLights(r, selectionWeights(c.solid_angles_sr, c.selectable), c.m);
}
process.stdout.write(JSON.stringify(out));
