// Validate a .glb with the Khronos glTF validator (https://www.npmjs.com/package/gltf-validator) and print
// its report as JSON. Usage: node tools/validate_gltf.mjs NPM_DIR file.glb
// NPM_DIR is the folder where `npm install gltf-validator@2.0.0-dev.3.10` ran; the import goes through a
// file URL because ES modules ignore NODE_PATH.
import { readFileSync } from 'fs';
import path from 'path';
import { pathToFileURL } from 'url';

const [npmDir, input] = process.argv.slice(2);
const entry = path.join(npmDir, 'node_modules', 'gltf-validator', 'index.js');
const validator = (await import(pathToFileURL(entry).href)).default;
const report = await validator.validateBytes(new Uint8Array(readFileSync(input)), { maxIssues: 1000 });
console.log(JSON.stringify(report));
