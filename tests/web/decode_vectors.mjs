// Decodes every tests/protocol_vectors/*.bin with web/src/protocol.js and prints one JSON
// object {name: decoded-or-error} on stdout, for tests/web/test_protocol_js.py to compare.
import { readdirSync, readFileSync } from 'node:fs';
import { join } from 'node:path';
import { decodeMessage, ProtocolError } from '../../web/src/protocol.js';

const dir = process.argv[2];
const out = {};
for (const file of readdirSync(dir).filter((f) => f.endsWith('.bin')).sort()) {
  const name = file.slice(0, -4);
  const bytes = readFileSync(join(dir, file)); // a Node Buffer: a view with a byteOffset
  try {
    const m = decodeMessage(bytes);
    const entry = {
      type: m.type, type_name: m.typeName, version: m.version, flags: m.flags,
      sequence: m.sequence, capture_time_s: m.captureTime, count: m.count,
    };
    if (m.rgb) {
      Object.assign(entry, { stale: m.stale, saturated_flag: m.saturatedFlag,
        simulated: m.simulated, replay: m.replay });
      entry.rgb = [];
      for (let i = 0; i < m.count; i++) entry.rgb.push(Array.from(m.rgb.subarray(3 * i, 3 * i + 3)));
      entry.saturated = [];
      m.saturated.forEach((bit, i) => { if (bit) entry.saturated.push(i); });
      entry.sun = m.sun && { direction: m.sun.direction,
        normal_irradiance: m.sun.normalIrradiance, source: m.sun.source,
        estimated: m.sun.estimated };
    } else {
      entry.payload_hex = Buffer.from(m.payload).toString('hex');
    }
    out[name] = entry;
  } catch (err) {
    if (!(err instanceof ProtocolError)) throw err;
    out[name] = { error: err.message };
  }
}
process.stdout.write(JSON.stringify(out));
