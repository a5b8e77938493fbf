// Write an INRIA PLY as SPZ version 2 with spz-js (https://www.npmjs.com/package/spz-js).
// Usage: node tools/spz_js_write.mjs NPM_DIR in.ply out.spz
// NPM_DIR is the folder where `npm install spz-js@1.2.5` ran (tools/make_spz_fixtures.py makes it);
// the import goes through a file URL because ES modules ignore NODE_PATH.
import { createReadStream, writeFileSync } from 'fs';
import path from 'path';
import { Readable } from 'stream';
import { pathToFileURL } from 'url';

const [npmDir, input, output] = process.argv.slice(2);
const entry = path.join(npmDir, 'node_modules', 'spz-js', 'dist', 'index.js');
const { loadPly, serializeSpz } = await import(pathToFileURL(entry).href);
const cloud = await loadPly(Readable.toWeb(createReadStream(input)));
writeFileSync(output, Buffer.from(await serializeSpz(cloud)));
