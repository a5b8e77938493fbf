// The gspc viewer: fetches the .gspc file named by `?file=URL`, decodes it tile by tile in a Web Worker
// (../src/decodeInWorker.mjs) as its bytes arrive, and draws each tile as soon as it is decoded, with the
// scene's up axis up (axes.mjs) and orbit controls. Every failure is one visible line.
//
// Query: file (the .gspc URL), source ('stream': one GET read as it arrives, the default; 'range': HTTP
// range requests), region (x0,y0,z0,x1,y1,z1: only the tiles that meet this box), digest (1: keep the
// decoded arrays for window.gspcViewer.digests(), for tests).
//
// window.gspcViewer, for tests and scripts: `shown` (a promise of {tiles, count, seconds, firstSeconds}
// once every tile is drawn: seconds from the start to the last tile drawn and to the first; rejected with
// the error), setCamera(w2c, fx, fy, cx, cy, width, height) (an OpenCV camera,
// world-to-camera row-major, in the file's coordinates), capture() (a PNG data URL of the settled view),
// digests() (each decoded attribute's SHA-256 over all tiles in file order, with ?digest=1).

import { decodeInWorker } from '../src/decodeInWorker.mjs';
import { conventionOf, frameOf, initialView, isRightHanded, mirrorBoxX, mirrorTileX, mirroredX } from './axes.mjs';
import { FOV_DEGREES, SplatView } from './splats.mjs';

const ATTRIBUTES = ['means', 'quats', 'logScales', 'opacities', 'shDc', 'shRest'];
const statusBox = document.getElementById('status');
const errorBox = document.getElementById('error');
const params = new URLSearchParams(location.search);

const megabytes = (bytes) => (bytes / 1e6).toFixed(bytes < 1e7 ? 2 : 1);

function parseRegion(text) {
  if (text === null) return null;
  const box = text.split(',').map(Number);
  if (box.length !== 6 || !box.every(Number.isFinite) || [0, 1, 2].some((a) => box[a] > box[a + 3])) {
    throw new Error(`region=${text}: give six numbers x0,y0,z0,x1,y1,z1, each low value at most its high one`);
  }
  return box;
}

let settle;
const shown = new Promise((resolve, reject) => {
  settle = { resolve, reject };
});
shown.catch(() => {}); // reported on the page; a script awaiting it sees the rejection too

function fail(err) {
  const name = err && err.name && err.name !== 'Error' ? `${err.name}: ` : '';
  errorBox.textContent = `Cannot show ${params.get('file') ?? 'the scene'}: ${name}${err && err.message ? err.message : err}`;
  errorBox.hidden = false;
  statusBox.hidden = true;
  settle.reject(err);
}

async function main() {
  const file = params.get('file');
  if (!file) throw new Error('no file to show: open the viewer with ?file=URL of a .gspc file (gspc view scene.gspc does)');
  const region = parseRegion(params.get('region'));
  const keep = params.get('digest') === '1';
  const name = decodeURIComponent(file.split('/').pop());
  const view = new SplatView(document.getElementById('view'));
  const start = performance.now();
  const kept = Object.fromEntries(ATTRIBUTES.map((k) => [k, []]));
  let head = null;
  let convention = null;
  let mirror = false;
  let framed = false;
  let received = 0;
  let size = 0;
  let tilesShown = 0;
  let shownCount = 0;
  let firstSeconds = null;
  let drawing = Promise.resolve();

  const update = () => {
    if (!head) {
      statusBox.textContent = `Fetching ${name}: ${megabytes(received)}${size ? ` of ${megabytes(size)}` : ''} MB`;
      return;
    }
    const tiles = region ? 'tiles' : `${head.tiles.length} tiles`;
    statusBox.textContent =
      `${name}: ${tilesShown} of ${tiles} shown, ${shownCount.toLocaleString('en')} of ` +
      `${head.count.toLocaleString('en')} Gaussians; ${megabytes(received)} of ${megabytes(size)} MB`;
  };
  const frame = (boxes, counts) => {
    const f = frameOf(mirror ? boxes.map(mirrorBoxX) : boxes, counts);
    view.setView(initialView(convention, f, FOV_DEGREES), f.radius);
    framed = true;
  };

  window.gspcViewer.setCamera = (...args) => view.setCameraOpenCV(...args);
  window.gspcViewer.capture = () => view.capture();
  update();
  const { whole } = await decodeInWorker(file, {
    region,
    mode: params.get('source') === 'range' ? 'range' : 'stream',
    onProgress(r, s) {
      received = r;
      size = s ?? 0;
      update();
    },
    onHead(h) {
      head = h;
      convention = conventionOf(h.coordinates);
      mirror = !isRightHanded(convention);
      if (mirror) convention = mirroredX(convention);
      view.setBackground(h.background);
      if (h.tiled) frame(h.tiles.map((t) => t.box), h.tiles.map((t) => t.count));
      update();
    },
    onTile(tile) {
      if (keep) for (const k of ATTRIBUTES) kept[k].push(tile[k].slice());
      if (mirror) mirrorTileX(tile);
      if (!framed) frame([tile.box], [tile.count]);
      drawing = drawing.then(async () => {
        await view.addTile(tile);
        if (firstSeconds === null) firstSeconds = (performance.now() - start) / 1000;
        tilesShown++;
        shownCount += tile.count;
        update();
      });
    },
  });
  await drawing;
  const seconds = (performance.now() - start) / 1000;
  const what = whole ? `${shownCount.toLocaleString('en')} Gaussians` : `${shownCount.toLocaleString('en')} Gaussians of the region`;
  statusBox.textContent = `${name}: ${what} in ${tilesShown} tile${tilesShown === 1 ? '' : 's'}, ${megabytes(size)} MB, shown in ${seconds.toFixed(1)} s. Drag to orbit, scroll to zoom.`;
  window.gspcViewer.digests = async () => {
    if (!keep) throw new Error('open the viewer with digest=1 to keep the decoded arrays');
    const out = {};
    for (const k of ATTRIBUTES) {
      const total = kept[k].reduce((n, a) => n + a.byteLength, 0);
      const all = new Uint8Array(total);
      let at = 0;
      for (const a of kept[k]) {
        all.set(new Uint8Array(a.buffer, a.byteOffset, a.byteLength), at);
        at += a.byteLength;
      }
      const digest = await crypto.subtle.digest('SHA-256', all);
      out[k] = Array.from(new Uint8Array(digest), (b) => b.toString(16).padStart(2, '0')).join('');
    }
    return out;
  };
  settle.resolve({ tiles: tilesShown, count: shownCount, seconds, firstSeconds });
}

window.gspcViewer = { shown };
main().catch(fail);
