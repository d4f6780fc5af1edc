// Decodes the mask payload of every tests/protocol_vectors/occlusion_rle_*.bin with
// web/src/protocol.js and prints {name: {width, height, people, set_count, spans} | {error}}
// for tests/web/test_protocol_js.py to compare with NAME.mask.json.
import { readdirSync, readFileSync } from 'node:fs';
import { join } from 'node:path';
import { decodeMessage, decodeOcclusionMask, ProtocolError } from '../../web/src/protocol.js';

const dir = process.argv[2];
const out = {};
for (const file of readdirSync(dir).filter((f) => /^occlusion_rle_.*\.bin$/.test(f)).sort()) {
  const name = file.slice(0, -4);
  try {
    const msg = decodeMessage(readFileSync(join(dir, file)));
    const m = decodeOcclusionMask(msg.payload);
    const spans = [];
    for (let row = 0; row < m.height; row++) {
      let x = 0;
      while (x < m.width) {
        if (m.mask[row * m.width + x]) {
          const x0 = x;
          while (x < m.width && m.mask[row * m.width + x]) x++;
          spans.push([row, x0, x]);
        } else x++;
      }
    }
    out[name] = { width: m.width, height: m.height, people: m.people, set_count: m.setCount, spans };
  } catch (err) {
    if (!(err instanceof ProtocolError)) throw err;
    out[name] = { error: err.message };
  }
}
process.stdout.write(JSON.stringify(out));
