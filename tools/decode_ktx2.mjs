// Decode Basis Universal KTX2 files to raw RGBA8 with three.js's own Basis transcoder (the
// wasm module the browser's KTX2Loader runs), for tests and `daylit probe --compact`.
// Usage: node tools/decode_ktx2.mjs IN1.ktx2 OUT1.bin [IN2.ktx2 OUT2.bin ...]
// Each OUT.bin: a little-endian uint32 header [width, height, layers, levels, isUASTC], then
// the RGBA8 pixels of level 0 of each layer in order, rows from the top.
//
//    or: node tools/decode_ktx2.mjs --serve
// One process for many decodes (bake/ktx2decoder.py; loading the transcoder is most of a short
// run's CPU). Requests on stdin, each a little-endian uint32 byte count and the UTF-8 path of
// a KTX2 file; one answer per request on stdout, in order: uint32 status (0 decoded, 1
// failed), uint32 byte count, then the bytes (an OUT.bin as above, or the error message).
// The process ends when stdin is closed.
import { readFileSync, writeFileSync } from "node:fs";
import { createRequire } from "node:module";
import { dirname, join } from "node:path";
import vm from "node:vm";

const require = createRequire(import.meta.url);
const basisDir = join(dirname(require.resolve("three")), "..", "examples", "jsm", "libs", "basis");
const RGBA32 = 13; // BasisTranscoder TranscoderFormat.RGBA32

const args = process.argv.slice(2);
const serve = args.length === 1 && args[0] === "--serve";
if (!serve && (args.length === 0 || args.length % 2)) {
  console.error("usage: node tools/decode_ktx2.mjs IN.ktx2 OUT.bin [IN.ktx2 OUT.bin ...]");
  console.error("   or: node tools/decode_ktx2.mjs --serve");
  process.exit(2);
}
// The transcoder is an Emscripten script meant for a browser worker; run it in a context of
// its own with the few Node globals it looks for. Its messages go to stderr: stdout carries
// the answers when serving.
const toStderr = new console.Console({ stdout: process.stderr, stderr: process.stderr });
const context = {
  module: {}, exports: {}, process, require, console: toStderr, WebAssembly, URL,
  __filename: join(basisDir, "basis_transcoder.js"), __dirname: basisDir,
};
vm.runInNewContext(readFileSync(join(basisDir, "basis_transcoder.js"), "utf8") +
  "\nmodule.exports = BASIS;", context);
const basis = await context.module.exports({
  wasmBinary: readFileSync(join(basisDir, "basis_transcoder.wasm")),
});
basis.initializeBasis();

function decode(input) {
  const file = new basis.KTX2File(new Uint8Array(readFileSync(input)));
  try {
    if (!file.isValid()) throw new Error(`${input}: not a valid KTX2 file`);
    const width = file.getWidth();
    const height = file.getHeight();
    const layers = Math.max(1, file.getLayers());
    const levels = file.getLevels();
    if (!file.startTranscoding()) throw new Error(`${input}: startTranscoding failed`);
    const header = new Uint32Array([width, height, layers, levels, file.isUASTC() ? 1 : 0]);
    const parts = [Buffer.from(header.buffer)];
    for (let layer = 0; layer < layers; layer++) {
      const dst = new Uint8Array(file.getImageTranscodedSizeInBytes(0, layer, 0, RGBA32));
      if (!file.transcodeImage(dst, 0, layer, 0, RGBA32, 0, -1, -1)) {
        throw new Error(`${input}: layer ${layer} failed to transcode`);
      }
      parts.push(Buffer.from(dst.buffer));
    }
    return Buffer.concat(parts);
  } finally {
    file.close();
    file.delete();
  }
}

function answer(status, body) {
  const head = Buffer.alloc(8);
  head.writeUInt32LE(status, 0);
  head.writeUInt32LE(body.length, 4);
  process.stdout.write(head);
  process.stdout.write(body);
}

if (serve) {
  let pending = Buffer.alloc(0);
  process.stdin.on("data", (chunk) => {
    pending = pending.length ? Buffer.concat([pending, chunk]) : chunk;
    while (pending.length >= 4) {
      const size = pending.readUInt32LE(0);
      if (pending.length < 4 + size) break;
      const input = pending.subarray(4, 4 + size).toString("utf8");
      pending = pending.subarray(4 + size);
      let body;
      try {
        body = decode(input);
      } catch (error) {
        answer(1, Buffer.from(String(error?.message ?? error), "utf8"));
        continue;
      }
      answer(0, body);
    }
  });
} else {
  for (let i = 0; i < args.length; i += 2) writeFileSync(args[i + 1], decode(args[i]));
}
