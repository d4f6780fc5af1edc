// Validate a glTF/GLB file with the Khronos glTF Validator; print its report as JSON.
// Usage: node tools/validate_gltf.mjs FILE.glb   (exit status 1 when it has errors)
import { readFileSync } from "node:fs";
import validator from "gltf-validator";

const file = process.argv[2];
if (!file) {
  console.error("usage: node tools/validate_gltf.mjs FILE.glb");
  process.exit(2);
}
const report = await validator.validateBytes(new Uint8Array(readFileSync(file)), {
  uri: file,
  maxIssues: 100,
});
console.log(JSON.stringify(report));
process.exit(report.issues.numErrors > 0 ? 1 : 0);
