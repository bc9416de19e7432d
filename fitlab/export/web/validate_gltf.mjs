// The Khronos glTF validator (npm gltf-validator) on one file: prints its JSON report.
// Usage: node validate_gltf.mjs FILE.gltf, from a folder where the package gltf-validator
// resolves (fitlab.export.threejs.validate copies it beside a link to node_modules)
import { readFileSync } from 'node:fs';
import validator from 'gltf-validator';

const path = process.argv[2];
const report = await validator.validateBytes(new Uint8Array(readFileSync(path)), {
  uri: path,
  maxIssues: 100,
  externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri}: fitlab's exports embed their buffers`)),
});
process.stdout.write(JSON.stringify(report.issues) + '\n');
