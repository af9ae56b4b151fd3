// Validates one glTF or GLB file with the Khronos glTF-Validator (npm gltf-validator) and
// prints its JSON report on stdout; exit code 0 when the report has no errors, 1 otherwise.
// Usage: node tools/validate-gltf.js FILE
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

const file = process.argv[2];
if (!file) {
  console.error("usage: node validate-gltf.js FILE.glb");
  process.exit(2);
}
const data = new Uint8Array(fs.readFileSync(file));
validator.validateBytes(data, {
  uri: path.basename(file),
  maxIssues: 200,
  // a .glb carries its buffers; nothing external is read
  externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} not allowed`)),
}).then((report) => {
  process.stdout.write(JSON.stringify(report));
  process.exit(report.issues.numErrors > 0 ? 1 : 0);
}, (err) => {
  console.error(String(err));
  process.exit(2);
});
