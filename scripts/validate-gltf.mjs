#!/usr/bin/env node
// Validate a .gltf file (and the buffers and images it references) with the Khronos
// glTF validator (npm package gltf-validator, installed by scripts/test-tools.sh into
// tools/node_modules). Prints the validator's JSON report; exit 0 when it has no errors.
import { readFile } from "node:fs/promises";
import path from "node:path";
import { createRequire } from "node:module";

const require = createRequire(import.meta.url);
const here = path.dirname(new URL(import.meta.url).pathname);
const validator = require(path.join(here, "..", "tools", "node_modules", "gltf-validator"));

const file = process.argv[2];
if (!file) {
  console.error("usage: validate-gltf.mjs FILE.gltf");
  process.exit(2);
}
const data = new Uint8Array(await readFile(file));
const report = await validator.validateBytes(data, {
  uri: path.basename(file),
  maxIssues: 1000,
  externalResourceFunction: (uri) =>
    readFile(path.join(path.dirname(file), decodeURIComponent(uri))).then((b) => new Uint8Array(b)),
});
console.log(JSON.stringify(report, null, 1));
process.exit(report.issues.numErrors === 0 ? 0 : 1);
