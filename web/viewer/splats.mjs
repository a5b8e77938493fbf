// The renderer: Spark (@sparkjsdev/spark) on three.js, chosen by measurement (bench/web.md, "Choosing the
// renderer"). Each decoded tile becomes one SplatMesh, built from the tile's INRIA PLY bytes (Spark's own
// reader of the layout gspc decodes to); Spark sorts the splats of all meshes together. Frames are drawn on
// demand: when the camera moves, a tile arrives or Spark's sort of the current view completes.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { SparkRenderer, SplatMesh } from '@sparkjsdev/spark';
import { writePly } from '../src/ply.mjs';

export const FOV_DEGREES = 50;
// Spark's options that follow the renderer rules of spec 10.12 where it has one: 0.3 px^2 added to the
// projected covariance without opacity compensation (rule 2), alphas below 1/255 skipped (rule 5), splats
// sorted by camera z (rule 6), each drawn out to alpha 1/255 of an opaque one, sqrt(2 ln 255) = 3.33
// standard deviations (rule 8). bench/web.md, "Choosing the renderer", measures what each changes.
const RULES = { preBlurAmount: 0.3, blurAmount: 0, minAlpha: 1 / 255, sortRadial: false, maxStdDev: Math.sqrt(2 * Math.log(255)) };
// Settling a view for capture(): a render starts Spark's update of the view within a few event-loop turns
// (SETTLE_MS), a sort may then take seconds on a software renderer (SORT_WAIT_MS at most), and a view is
// settled once a render starts no new sort.
const SETTLE_MS = 100;
const POLL_MS = 20;
const SORT_WAIT_MS = 60000;
const MAX_SETTLE_ROUNDS = 10;
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

export class SplatView {
  constructor(container) {
    this.renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    container.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(FOV_DEGREES, 1, 0.01, 1000);
    this.dirty = 0;
    this.spark = new SparkRenderer({ renderer: this.renderer, ...RULES, onDirty: () => this.sortDone() });
    this.scene.add(this.spark);
    this.controls = null;
    this.pending = false;
    this.fixedSize = false;
    this.meshes = [];
    this.resize();
    window.addEventListener('resize', () => this.resize());
  }

  sortDone() {
    this.dirty++;
    this.requestRender();
  }

  resize() {
    if (this.fixedSize) return;
    this.setSize(window.innerWidth, window.innerHeight);
  }

  setSize(width, height) {
    this.renderer.setSize(width, height);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }

  setBackground([r, g, b]) {
    this.renderer.setClearColor(new THREE.Color(r, g, b), 1);
    this.requestRender();
  }

  /** Orbit controls around `target`, the camera at `position` with `up` (file coordinates) its up. */
  setView({ position, target, up }, radius) {
    this.camera.up.set(...up);
    this.camera.position.set(...position);
    this.camera.near = radius / 1000;
    this.camera.far = radius * 1000;
    this.camera.updateProjectionMatrix();
    if (this.controls) this.controls.dispose();
    // OrbitControls reads the camera's up when it is made.
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.target.set(...target);
    this.controls.addEventListener('change', () => this.requestRender());
    this.controls.update();
    this.requestRender();
  }

  /** Add a decoded tile ({count, shDegree, means, ...}); resolves once Spark has it. */
  async addTile(tile) {
    const mesh = new SplatMesh({ fileBytes: writePly(tile), fileType: 'ply' });
    await mesh.initialized;
    this.scene.add(mesh);
    this.meshes.push(mesh);
    this.requestRender();
  }

  clear() {
    for (const mesh of this.meshes) {
      this.scene.remove(mesh);
      mesh.dispose();
    }
    this.meshes = [];
    this.requestRender();
  }

  requestRender() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.renderer.render(this.scene, this.camera);
    });
  }

  /**
   * Place the camera of an OpenCV world-to-camera matrix (`w2c`: 16 numbers, row-major, x right, y down, z
   * forward) and pinhole intrinsics, at `width` x `height` CSS pixels: the projection is the pinhole's,
   * principal point included.
   */
  setCameraOpenCV(w2c, fx, fy, cx, cy, width, height) {
    this.fixedSize = true;
    this.renderer.setPixelRatio(1);
    this.setSize(width, height);
    if (this.controls) this.controls.enabled = false;
    // three.js cameras look down -z with y up: camera-to-world is OpenCV's with y and z turned.
    const c2w = new THREE.Matrix4().fromArray(w2c).transpose().invert().multiply(new THREE.Matrix4().makeScale(1, -1, -1));
    const scale = new THREE.Vector3();
    c2w.decompose(this.camera.position, this.camera.quaternion, scale);
    const n = this.camera.near;
    const f = this.camera.far;
    const w = width;
    const h = height;
    this.camera.projectionMatrix.set(
      (2 * fx) / w, 0, 1 - (2 * cx) / w, 0,
      0, (2 * fy) / h, (2 * cy) / h - 1, 0,
      0, 0, -(f + n) / (f - n), (-2 * f * n) / (f - n),
      0, 0, -1, 0,
    );
    this.camera.projectionMatrixInverse.copy(this.camera.projectionMatrix).invert();
    this.camera.updateMatrixWorld(true);
  }

  /**
   * Draw the current view once Spark's sort for it is done (its worker sorts after the view changes, and
   * draws with the previous order meanwhile); the canvas as a PNG data URL.
   */
  async capture() {
    const spark = this.spark;
    const busy = () => spark.sorting || spark.sortDirty;
    for (let round = 0; round < MAX_SETTLE_ROUNDS; round++) {
      const sorts = spark.lastSortTime;
      this.renderer.render(this.scene, this.camera);
      await sleep(SETTLE_MS);
      const start = performance.now();
      while (busy() && performance.now() - start < SORT_WAIT_MS) await sleep(POLL_MS);
      if (!busy() && spark.lastSortTime === sorts) break;
    }
    this.renderer.render(this.scene, this.camera);
    return this.renderer.domElement.toDataURL('image/png');
  }
}
