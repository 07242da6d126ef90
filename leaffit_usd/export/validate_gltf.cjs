// Validate one .glb/.gltf with the Khronos glTF-Validator (npm "gltf-validator") and print its
// JSON report on stdout. Usage: node validate_gltf.cjs FILE   (NODE_PATH must reach the module)
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

const file = process.argv[2];
const bytes = new Uint8Array(fs.readFileSync(file));
validator.validateBytes(bytes, {
  uri: path.basename(file),
  maxIssues: 0,
  externalResourceFunction: (uri) => new Promise((resolve, reject) => {
    try { resolve(new Uint8Array(fs.readFileSync(path.resolve(path.dirname(file), decodeURIComponent(uri))))); }
    catch (e) { reject(e.toString()); }
  }),
}).then((report) => {
  process.stdout.write(JSON.stringify(report));
}).catch((e) => {
  process.stderr.write(String(e) + "\n");
  process.exit(1);
});
