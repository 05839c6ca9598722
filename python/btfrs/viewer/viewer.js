// The btfrs viewer: loads a model exported by btfrs.web (model/manifest.json beside the page,
// or the JSON script element of the single-file export) and draws it with WebGPU using the
// project's own shader. A single-view model (an RTI capture's) is shown in the 2D view ("image",
// rti.js): straight on, panned and zoomed, in RTIViewer's rendering modes, its state in the
// page's address; a tiled model (tiles.js) is fetched tile by tile, coarsest level first.
// `window.btfrsViewer` is its scripting interface (see below).

import { discToLight, orbitCamera, panCamera, vec3Normalize, vec3Length } from "./math.js";
import { openGpu, createRenderer } from "./gpu.js";
import { buildUi } from "./ui.js";
import { KNOWN_KINDS } from "./kinds.js";
import { RTI_MODES, rtiLevelFor, rtiWindow, rtiUniform, rtiVisible } from "./rti.js";
import { openTiles } from "./tiles.js";

const WEB_FORMAT = "btfrs-web";
const WEB_VERSION = 2;
// The 2D view's name among the scenes.
const IMAGE = "image";
// Screen pixels per texel at the closest zoom, and the farthest zoom as a part of the fit.
const MAX_ZOOM = 64;
const MIN_ZOOM_OF_FIT = 0.25;

function base64ToBytes(text) {
  const bin = atob(text);
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}

function bytesToBase64(bytes) {
  let s = "";
  const step = 0x8000;
  for (let i = 0; i < bytes.length; i += step) s += String.fromCharCode.apply(null, bytes.subarray(i, i + step));
  return btoa(s);
}

// The files the page needs, as the manifest names them.
function neededFiles(manifest) {
  const names = new Set(Object.values(manifest.files));
  if (manifest.volume) names.add(manifest.volume.file);
  if (manifest.map) names.add(manifest.map.file);
  for (const s of Object.values(manifest.scenes)) {
    names.add(s.vertices);
    names.add(s.indices);
  }
  return [...names];
}

function checkManifest(manifest) {
  if (!manifest || manifest.format !== WEB_FORMAT) {
    throw new Error(`this is not a btfrs web export (format ${JSON.stringify(manifest && manifest.format)}, ` +
      `expected "${WEB_FORMAT}")`);
  }
  if (manifest.version !== WEB_VERSION) {
    throw new Error(`the model was exported as btfrs-web version ${JSON.stringify(manifest.version)}; this viewer ` +
      `reads version ${WEB_VERSION}: export the model again with the btfrs that wrote this viewer`);
  }
  const kind = manifest.model && manifest.model.kind;
  if (!KNOWN_KINDS.includes(kind)) {
    throw new Error(`unknown model kind ${JSON.stringify(kind)}; this viewer draws ${KNOWN_KINDS.join(", ")}`);
  }
}

function modelBase() {
  return new URL("model/", document.baseURI);
}

// The manifest and the files (name -> Uint8Array), from the page or from model/ beside it.
async function loadData() {
  const embedded = document.getElementById("btfrs-data");
  if (embedded) {
    const data = JSON.parse(embedded.textContent);
    checkManifest(data.manifest);
    const files = {};
    for (const n of neededFiles(data.manifest)) {
      if (!(n in data.files)) throw new Error(`the page's model data has no file "${n}"`);
      files[n] = base64ToBytes(data.files[n]);
    }
    return { manifest: data.manifest, files };
  }
  const base = modelBase();
  const res = await fetch(new URL("manifest.json", base));
  if (!res.ok) throw new Error(`cannot load model/manifest.json beside the page (HTTP ${res.status})`);
  const manifest = await res.json();
  checkManifest(manifest);
  const files = {};
  await Promise.all(neededFiles(manifest).map(async (n) => {
    const r = await fetch(new URL(n, base));
    if (!r.ok) throw new Error(`cannot load model/${n} (HTTP ${r.status})`);
    files[n] = new Uint8Array(await r.arrayBuffer());
  }));
  return { manifest, files };
}

// What the surface shows besides the sample: a synthesized coordinate map or a Wang tiling.
function surfaceText(manifest) {
  const m = manifest.map;
  if (!m) return "";
  if (m.kind === "tiles") return `Wang tiling of ${m.tiles[2]} x ${m.tiles[1]} tiles of ${m.tiles[0]}^2`;
  return `synthesized texture of ${m.map_size[0]} x ${m.map_size[1]} texels`;
}

function asVec3(name, v) {
  if (!Array.isArray(v) || v.length !== 3 || !v.every((x) => typeof x === "number" && Number.isFinite(x))) {
    throw new Error(`${name}: expected three finite numbers, got ${JSON.stringify(v)}`);
  }
  return v.slice();
}

// --- The viewer's state and its frames --------------------------------------------------------

const viewerState = {
  light: [0, 0, 1],
  intensity: [1, 1, 1],
  sky: false,
  camera: null,
  scene: "plane",
  exposure: 1,
  size: [512, 512],
  // The 2D view: its mode and the modes' parameters; the zoom (screen pixels per image texel)
  // and the image point at the canvas centre (texels from the top left), null: fit the canvas.
  mode: "default",
  gain: 2,
  kd: 0.6,
  ks: 0.5,
  exponent: 40,
  zoom: null,
  center: null,
};
// Whether the canvas follows its box on the page (until a size is set).
let autoSize = true;
let tileSource = null;
// The window whose texels the store holds (a tiled model), and the last one drawn.
let storeWindow = null;
let drawnWindow = null;
let firstImageFrame = null;
let viewerRenderer = null;
let viewerUi = null;
let viewerManifest = null;
let viewerInfo = null;
let frameDirty = false;
let frameLoop = null;
let frameWaiters = [];

function fail(e) {
  const text = e && e.message ? e.message : String(e);
  if (!api.error) api.error = text;
  if (viewerUi) {
    viewerUi.showMessage(api.error);
  } else {
    const m = document.getElementById("message") || document.body.appendChild(document.createElement("div"));
    m.textContent = api.error;
  }
}

function isImage() {
  return viewerState.scene === IMAGE;
}

function imageSize() {
  return [viewerManifest.model.width, viewerManifest.model.height];
}

function fitZoom() {
  const [w, h] = imageSize();
  return Math.min(viewerState.size[0] / w, viewerState.size[1] / h);
}

// The 2D view's geometry: canvas size, zoom, centre.
function imageView() {
  const [w, h] = imageSize();
  return {
    width: viewerState.size[0],
    height: viewerState.size[1],
    zoom: viewerState.zoom === null ? fitZoom() : viewerState.zoom,
    center: viewerState.center === null ? [w / 2, h / 2] : viewerState.center,
  };
}

// The window to draw: the whole model, or for a tiled one the finest level at or below the one
// the zoom asks for whose tiles under the canvas have arrived (the level asked for is fetched).
function imageWindow(view) {
  const size = imageSize();
  if (!tileSource) {
    return { level: 0, x0: 0, y0: 0, w: size[0], h: size[1], levelSize: size, scale: 1 };
  }
  const n = tileSource.levels;
  const tile = tileSource.tile;
  let want = rtiLevelFor(view.zoom, n);
  let win = rtiWindow(view, size, n, want, tile);
  while (want > 0 && win.w * win.h > tileSource.capacity) {
    want--;
    win = rtiWindow(view, size, n, want, tile);
  }
  tileSource.request(want, win);
  for (let l = want; l >= 0; l--) {
    const w = l === want ? win : rtiWindow(view, size, n, l, tile);
    if (w.w * w.h <= tileSource.capacity && tileSource.loaded(l, w)) return w;
  }
  return null;
}

function sameWindow(a, b) {
  return a && b && a.level === b.level && a.x0 === b.x0 && a.y0 === b.y0 && a.w === b.w && a.h === b.h;
}

// A frame of the 2D view: the window's texels into the store when it changed, then its uniforms.
function imageFrame(renderer) {
  const view = imageView();
  const win = imageWindow(view);
  if (!win) throw new Error("no tile of the image has arrived yet");
  if (tileSource && !sameWindow(win, storeWindow)) {
    const parts = tileSource.assemble(win.level, win);
    viewerManifest.tiles.texels.forEach((p, i) => renderer.writeStore(p.offset, parts[i]));
    storeWindow = win;
  }
  drawnWindow = win;
  const s = { ...viewerState };
  // Two passes where the texels under the canvas are no more than its pixels (a magnified
  // view: each texel relit once), one where they are more.
  const vis = rtiVisible(view, win);
  const texels = vis.w * vis.h <= view.width * view.height && Math.max(vis.w, vis.h) <= 8192 ? vis : null;
  return {
    image: rtiUniform(view, win, viewerManifest.rti, s, imageSize(), texels),
    texels,
    sampleSize: [win.w, win.h],
    raw: viewerState.mode === "normals",
    exposure: viewerState.exposure,
    width: view.width,
    height: view.height,
  };
}

function currentView(renderer = viewerRenderer) {
  if (isImage()) return imageFrame(renderer);
  return {
    camera: viewerState.camera,
    // The sky: its importance-sampled directional lights (what btfrs.render's
    // lighting="sampled" draws) plus the light of the disc, as the native renderer adds them.
    lights: (viewerState.sky && viewerManifest.environment ? viewerManifest.environment.lights : [])
      .concat(viewerState.intensity.some((x) => x > 0) ? [{ direction: viewerState.light, intensity: viewerState.intensity }] : []),
    scene: viewerState.scene,
    exposure: viewerState.exposure,
    width: viewerState.size[0],
    height: viewerState.size[1],
  };
}

async function drawFrames() {
  while (frameDirty) {
    frameDirty = false;
    const waiters = frameWaiters;
    frameWaiters = [];
    try {
      if (api.error) throw new Error(api.error);
      ({ ms: api.frameMs, drawMs: api.drawMs } = await viewerRenderer.render(currentView()));
      api.frames += 1;
      waiters.forEach((w) => w.resolve());
    } catch (e) {
      fail(e);
      waiters.forEach((w) => w.reject(e));
    }
  }
  frameLoop = null;
}

// A frame with the current state; resolves once drawn. Requests made while a frame is being
// drawn share the next one.
function requestFrame() {
  const p = new Promise((resolve, reject) => frameWaiters.push({ resolve, reject }));
  frameDirty = true;
  if (!frameLoop && viewerRenderer) frameLoop = drawFrames();
  return p;
}

// A frame asked for by the page's controls: failures are shown by fail().
function redraw() {
  requestFrame().catch(() => {});
}

function showState() {
  if (!viewerUi) return;
  viewerUi.setLight(viewerState.light);
  viewerUi.setExposure(viewerState.exposure);
  viewerUi.setScene(viewerState.scene);
  viewerUi.setSky(viewerState.sky, Boolean(viewerManifest && viewerManifest.environment) && !isImage());
  viewerUi.setMode(viewerState, isImage(), autoSize);
  writeAddress();
}

// --- The 2D view's state in the page's address ------------------------------------------------
// `#light=x,y&mode=specular&kd=0.6&ks=0.5&exponent=40&zoom=2&center=512,384&exposure=1`: what a
// shared link opens with (the light is the point of the disc; the mode's own parameters only).

const MODE_PARAMS = { default: [], diffuse_gain: ["gain"], specular: ["kd", "ks", "exponent"], normals: [] };

function fmt(x, digits) {
  return String(Number(x.toFixed(digits)));
}

function addressOf() {
  const s = viewerState;
  const parts = [`light=${fmt(s.light[0], 4)},${fmt(s.light[1], 4)}`, `mode=${s.mode}`];
  for (const k of MODE_PARAMS[s.mode]) parts.push(`${k}=${fmt(s[k], 4)}`);
  if (s.zoom !== null) parts.push(`zoom=${fmt(s.zoom, 5)}`);
  if (s.center !== null) parts.push(`center=${fmt(s.center[0], 3)},${fmt(s.center[1], 3)}`);
  if (s.exposure !== 1) parts.push(`exposure=${fmt(s.exposure, 4)}`);
  return parts.join("&");
}

function writeAddress() {
  if (!viewerManifest || !isImage() || !window.history || !window.history.replaceState) return;
  const hash = `#${addressOf()}`;
  if (window.location.hash !== hash) window.history.replaceState(null, "", hash);
}

// The settings an address holds (unknown keys are an error naming them).
function settingsOf(hash) {
  const out = {};
  const text = hash.replace(/^#/, "");
  if (!text) return out;
  const nums = (k, v, n) => {
    const xs = v.split(",").map(Number);
    if (xs.length !== n || !xs.every(Number.isFinite)) throw new Error(`${k}: expected ${n} number(s), got ${JSON.stringify(v)}`);
    return xs;
  };
  for (const pair of text.split("&")) {
    const at = pair.indexOf("=");
    const k = decodeURIComponent(at < 0 ? pair : pair.slice(0, at));
    const v = decodeURIComponent(at < 0 ? "" : pair.slice(at + 1));
    if (k === "light") out.light = discToLight(...nums(k, v, 2));
    else if (k === "mode") out.mode = v;
    else if (["gain", "kd", "ks", "exponent", "zoom", "exposure"].includes(k)) out[k] = nums(k, v, 1)[0];
    else if (k === "center") out.center = nums(k, v, 2);
    else if (k === "size") {
      const m = /^(\d+)x(\d+)$/.exec(v);
      if (!m) throw new Error(`size: expected WIDTHxHEIGHT, got ${JSON.stringify(v)}`);
      out.size = [Number(m[1]), Number(m[2])];
    } else throw new Error(`unknown setting ${JSON.stringify(k)}`);
  }
  return out;
}

// Check and apply `set`'s settings all together (nothing changes when one is wrong).
function applySettings(s) {
  const next = { ...viewerState, camera: { ...viewerState.camera } };
  if (s.light !== undefined) {
    const l = asVec3("light", s.light);
    if (vec3Length(l) === 0) throw new Error("light: expected a non-zero direction");
    next.light = vec3Normalize(l);
  }
  if (s.intensity !== undefined) {
    const i = typeof s.intensity === "number" ? [s.intensity, s.intensity, s.intensity] : asVec3("intensity", s.intensity);
    if (!i.every((x) => Number.isFinite(x) && x >= 0)) throw new Error("intensity: expected non-negative values");
    next.intensity = i;
  }
  if (s.camera !== undefined) {
    const c = s.camera;
    if (c.eye !== undefined) next.camera.eye = asVec3("camera.eye", c.eye);
    if (c.target !== undefined) next.camera.target = asVec3("camera.target", c.target);
    if (c.up !== undefined) next.camera.up = asVec3("camera.up", c.up);
    if (c.fov !== undefined) {
      if (!(c.fov > 0 && c.fov < 180)) throw new Error(`camera.fov: expected degrees in (0, 180), got ${c.fov}`);
      next.camera.fov = Number(c.fov);
    }
    if (c.near !== undefined) next.camera.near = Number(c.near);
    if (c.far !== undefined) next.camera.far = Number(c.far);
    const d = [0, 1, 2].map((k) => next.camera.target[k] - next.camera.eye[k]);
    if (vec3Length(d) === 0) throw new Error("camera: eye and target must differ");
    if (vec3Length(next.camera.up) === 0) throw new Error("camera.up: expected a non-zero vector");
    if (!(next.camera.near > 0 && next.camera.far > next.camera.near)) throw new Error("camera: expected 0 < near < far");
  }
  if (s.sky !== undefined) {
    if (s.sky && !viewerManifest.environment) throw new Error("sky: this export has no environment light");
    next.sky = Boolean(s.sky);
  }
  if (s.scene !== undefined) {
    if (!(s.scene in viewerManifest.scenes) && !(s.scene === IMAGE && viewerManifest.rti)) {
      throw new Error(`scene: expected one of ${Object.keys(viewerManifest.scenes).join(", ")}, got ${JSON.stringify(s.scene)}`);
    }
    next.scene = s.scene;
  }
  if (s.exposure !== undefined) {
    if (!(typeof s.exposure === "number" && Number.isFinite(s.exposure) && s.exposure >= 0)) {
      throw new Error(`exposure: expected a number >= 0, got ${JSON.stringify(s.exposure)}`);
    }
    next.exposure = s.exposure;
  }
  if (s.size !== undefined) {
    const ok = Array.isArray(s.size) && s.size.length === 2 && s.size.every((x) => Number.isInteger(x) && x >= 1 && x <= 8192);
    if (!ok) throw new Error(`size: expected [width, height], integers in 1..8192, got ${JSON.stringify(s.size)}`);
    next.size = s.size.slice();
  }
  if (s.mode !== undefined) {
    if (!RTI_MODES.includes(s.mode)) throw new Error(`mode: expected one of ${RTI_MODES.join(", ")}, got ${JSON.stringify(s.mode)}`);
    if (s.mode !== "default" && !viewerManifest.rti) throw new Error("mode: only the 2D view of a single-view model has modes");
    next.mode = s.mode;
  }
  const positive = (k, lo, hi) => {
    if (s[k] === undefined) return;
    if (!(typeof s[k] === "number" && Number.isFinite(s[k]) && s[k] >= lo && s[k] <= hi)) {
      throw new Error(`${k}: expected a number in [${lo}, ${hi}], got ${JSON.stringify(s[k])}`);
    }
    next[k] = s[k];
  };
  positive("gain", 0, 100);
  positive("kd", 0, 10);
  positive("ks", 0, 10);
  positive("exponent", 0.1, 10000);
  if (s.zoom !== undefined) {
    if (s.zoom === null) next.zoom = null;
    else if (!(typeof s.zoom === "number" && s.zoom > 0 && s.zoom <= MAX_ZOOM)) {
      throw new Error(`zoom: expected screen pixels per texel in (0, ${MAX_ZOOM}], got ${JSON.stringify(s.zoom)}`);
    } else next.zoom = s.zoom;
  }
  if (s.center !== undefined) {
    const ok = s.center === null || (Array.isArray(s.center) && s.center.length === 2 && s.center.every(Number.isFinite));
    if (!ok) throw new Error(`center: expected [x, y] in texels, got ${JSON.stringify(s.center)}`);
    next.center = s.center === null ? null : s.center.slice();
  }
  if (s.scene === IMAGE && !viewerManifest.rti) throw new Error("scene: the image view is for single-view models");
  if (s.size !== undefined) autoSize = false;
  Object.assign(viewerState, next);
  showState();
}

// --- window.btfrsViewer -----------------------------------------------------------------------

let resolveReady;
let rejectReady;
const api = {
  // Resolves after the first frame; rejects (and `error` is set) when the viewer cannot draw.
  ready: new Promise((resolve, reject) => {
    resolveReady = resolve;
    rejectReady = reject;
  }),
  // The error shown in the page, or null.
  error: null,
  // Milliseconds of the last frame (from its encoding to the GPU's completion), of its model
  // pass alone (what the native renderer's draw time measures), frames drawn.
  frameMs: null,
  drawMs: null,
  frames: 0,
  // Milliseconds from the navigation's start: the model's files loaded, the first frame drawn.
  loadedMs: null,
  firstFrameMs: null,
  // Change any of light [x, y, z] (towards the light), intensity (number or RGB), camera
  // {eye, target, up, fov}, scene, exposure, size [width, height], and for the 2D view mode,
  // gain, kd, ks, exponent, zoom (screen pixels per texel; null: fit), center [x, y] (texels;
  // null: the image's centre); resolves after the new frame.
  async set(settings) {
    await api.ready;
    applySettings(settings || {});
    return requestFrame();
  },
  // The current settings (light, intensity, camera, scene, exposure, size, mode and its
  // parameters); in the 2D view the zoom and centre in effect, and the level and window drawn.
  state() {
    const out = JSON.parse(JSON.stringify(viewerState));
    if (viewerManifest && isImage()) {
      const v = imageView();
      out.zoom = v.zoom;
      out.center = v.center;
      out.window = drawnWindow ? { ...drawnWindow } : null;
      out.passes = drawnWindow && rtiVisible(v, drawnWindow).w * rtiVisible(v, drawnWindow).h <= v.width * v.height ? 2 : 1;
      out.address = addressOf();
    }
    return out;
  },
  // Resolves when every frame asked for so far is drawn, and every tile being fetched has
  // arrived and been drawn.
  async settled() {
    await api.ready;
    for (;;) {
      while (frameLoop) await frameLoop;
      if (tileSource && tileSource.pending()) {
        await tileSource.idle();
        continue;
      }
      if (!frameLoop) break;
    }
  },
  // A tiled model's fetches: {requested: tile URLs in order (relative to model/), levels,
  // first: the level and window of the first frame and the tiles it had}; null otherwise.
  tiles() {
    if (!tileSource) return null;
    return { requested: tileSource.requested.slice(), levels: tileSource.levels, pending: tileSource.pending(),
      first: firstImageFrame };
  },
  // The last frame, RGBA8, rows top first: {width, height, encoding: "base64", data} (once the
  // frames asked for are drawn; tiles still on their way are not waited for).
  async readPixels() {
    await api.ready;
    while (frameLoop) await frameLoop;
    const p = await viewerRenderer.readPixels();
    return { width: p.width, height: p.height, encoding: "base64", data: bytesToBase64(p.bytes) };
  },
  // The model and the adapter: kind, name, size [width, height], views, bytes, renderer,
  // adapter, presentation ("webgpu" canvas, or "2d" through a read-back).
  info() {
    return viewerInfo ? { ...viewerInfo } : null;
  },
};
api.ready.catch(() => {});
window.btfrsViewer = api;

const controls = {
  sky(on) {
    applySettings({ sky: on });
    redraw();
  },
  light(l) {
    applySettings({ light: l });
    redraw();
  },
  imageLight(x, y) {
    applySettings({ light: discToLight(x, y) });
    redraw();
  },
  scene(name) {
    applySettings({ scene: name });
    redraw();
  },
  exposure(v) {
    applySettings({ exposure: v });
    redraw();
  },
  mode(name) {
    applySettings({ mode: name });
    redraw();
  },
  modeParam(name, value) {
    applySettings({ [name]: value });
    redraw();
  },
  // A drag on the image: orbit around the target, or pan for a single-view model (its
  // appearance is known from one view only); in the 2D view, move the image with the pointer.
  orbit(dx, dy, rect) {
    if (!viewerRenderer || !rect.width || !rect.height) return;
    if (isImage()) {
      const v = imageView();
      const k = viewerState.size[0] / rect.width / v.zoom;
      viewerState.zoom = v.zoom;
      viewerState.center = [v.center[0] - dx * k, v.center[1] - dy * k];
      showState();
      redraw();
      return;
    }
    const c = viewerState.camera;
    if (viewerManifest.model.views === 1) {
      const k = (2 * Math.tan((c.fov * Math.PI) / 360)) / rect.height;
      viewerState.camera = panCamera(c, dx * k, dy * k, 1);
    } else {
      viewerState.camera = orbitCamera(c, (-dx / rect.width) * Math.PI, (dy / rect.height) * Math.PI, 1);
    }
    redraw();
  },
  // The wheel: in the 2D view the image point under the pointer (canvas pixels `at`) stays.
  zoom(factor, at) {
    if (!viewerRenderer) return;
    if (isImage()) {
      const v = imageView();
      const z = Math.min(MAX_ZOOM, Math.max(fitZoom() * MIN_ZOOM_OF_FIT, v.zoom / factor));
      const p = at || [v.width / 2, v.height / 2];
      const img = [v.center[0] + (p[0] - v.width / 2) / v.zoom, v.center[1] + (p[1] - v.height / 2) / v.zoom];
      viewerState.zoom = z;
      viewerState.center = [img[0] - (p[0] - v.width / 2) / z, img[1] - (p[1] - v.height / 2) / z];
      showState();
      redraw();
      return;
    }
    const c = viewerState.camera;
    viewerState.camera = viewerManifest.model.views === 1 ? panCamera(c, 0, 0, factor) : orbitCamera(c, 0, 0, factor);
    redraw();
  },
};

// The device, the renderer and the first frame, presented on a WebGPU canvas; where the
// browser cannot present one, with the frames read back into a 2D canvas. Headless Chromium
// (its user agent says so) loses the device at the first presented frame, and after a few
// such losses refuses WebGPU altogether: it reads back from the start. Elsewhere a device lost
// at the first frame is taken for the same failure, and the 2D way tried.
async function startGpu(manifest, files) {
  const largest = Math.max(...Object.values(files).map((f) => f.byteLength), manifest.tiles ? manifest.tiles.store_words * 4 : 0);
  const shaderCode = new TextDecoder().decode(files[manifest.files.shader]);
  const headless = /HeadlessChrome/.test(navigator.userAgent);
  let lastError = null;
  for (const present of headless ? ["2d"] : ["webgpu", "2d"]) {
    const gpu = await openGpu(largest, lastError !== null);
    const canvas = present === "webgpu" ? viewerUi.canvas : viewerUi.newCanvas();
    let current = false;
    let lost = null;
    gpu.device.addEventListener("uncapturederror", (ev) => {
      if (current) fail(new Error(`WebGPU error: ${ev.error.message}`));
    });
    gpu.device.lost.then((info) => {
      lost = info;
      if (current && info.reason !== "destroyed") fail(new Error(`the GPU device was lost: ${info.message}`));
      else if (current) fail(new Error("the GPU device was lost"));
    });
    const renderer = await createRenderer(gpu, manifest, files, shaderCode, canvas, present);
    storeWindow = null;
    try {
      const { ms, drawMs } = await renderer.render(currentView(renderer));
      // A lost device may only say so after the frame.
      await new Promise((r) => setTimeout(r, 0));
      if (lost) throw new Error(`the GPU device was lost: ${lost.message}`);
      current = true;
      if (tileSource) {
        firstImageFrame = { level: drawnWindow.level, window: { ...drawnWindow }, requested: tileSource.requested.slice() };
      }
      viewerRenderer = renderer;
      api.frameMs = ms;
      api.drawMs = drawMs;
      api.frames += 1;
      if (frameDirty && !frameLoop) frameLoop = drawFrames(); // the controls moved meanwhile
      return { gpu, present };
    } catch (e) {
      lastError = e;
      if (!lost) await Promise.race([gpu.device.lost, new Promise((r) => setTimeout(r, 200))]);
      if (!lost) throw e; // a real error, not the presentation
      gpu.device.destroy();
    }
  }
  throw lastError;
}

// The canvas's size from its box on the page (device pixels), in the 2D view.
function fitCanvas() {
  const c = viewerUi.canvas;
  const r = c.getBoundingClientRect();
  const dpr = window.devicePixelRatio || 1;
  if (r.width > 0 && r.height > 0) {
    viewerState.size = [Math.min(4096, Math.max(64, Math.round(r.width * dpr))), Math.min(4096, Math.max(64, Math.round(r.height * dpr)))];
  }
}

window.addEventListener("resize", () => {
  if (autoSize && viewerManifest && isImage() && viewerUi) {
    fitCanvas();
    redraw();
  }
});

async function start() {
  viewerUi = buildUi(document.getElementById("app") || document.body, controls);
  const { manifest, files } = await loadData();
  api.loadedMs = performance.now();
  viewerManifest = manifest;
  const cam = manifest.camera;
  viewerState.camera = { eye: cam.eye.slice(), target: cam.target.slice(), up: cam.up.slice(), fov: cam.fov,
    near: cam.near, far: cam.far };
  viewerState.light = vec3Normalize(manifest.light.direction);
  viewerState.intensity = manifest.light.intensity.slice();
  viewerState.exposure = manifest.exposure;
  const scenes = (manifest.rti ? [IMAGE] : []).concat(Object.keys(manifest.scenes));
  viewerState.scene = manifest.rti ? IMAGE : ("plane" in manifest.scenes ? "plane" : scenes[0]);
  if (manifest.rti) {
    const d = manifest.rti.defaults || {};
    for (const k of ["gain", "kd", "ks", "exponent"]) if (typeof d[k] === "number") viewerState[k] = d[k];
  }
  viewerUi.setScenes(scenes, viewerState.scene);
  viewerUi.setSky(false, Boolean(manifest.environment));
  viewerUi.setHelp(manifest.model.views === 1, isImage());
  // The view in the page's address (a shared link), then the canvas's own size on the page.
  if (manifest.rti && window.location.hash) {
    try {
      applySettings(settingsOf(decodeURIComponent(window.location.hash)));
    } catch (e) {
      viewerUi.showMessage(`the view in the address was not applied: ${e.message}`);
    }
  }
  if (autoSize && isImage()) {
    viewerUi.setMode(viewerState, true, true);
    fitCanvas();
  }
  showState();
  if (manifest.tiles) {
    tileSource = await openTiles(modelBase(), manifest, (err) => {
      if (err) fail(err);
      else redraw();
    });
    // The first frame at level 0 (one tile per image), before anything finer is asked for.
    const win = { level: 0, x0: 0, y0: 0, w: 1, h: 1 };
    tileSource.request(0, win);
    await tileSource.idle();
    if (tileSource.error) throw tileSource.error;
  }
  const { gpu, present } = await startGpu(manifest, files);
  viewerInfo = {
    kind: manifest.model.kind,
    name: manifest.model.name,
    size: [manifest.model.width, manifest.model.height],
    views: manifest.model.views,
    bytes: manifest.model.nbytes,
    renderer: manifest.model.renderer,
    surface: surfaceText(manifest),
    adapter: gpu.adapterName,
    presentation: present,
  };
  viewerUi.setFacts(viewerInfo);
}

start().then(
  () => {
    api.firstFrameMs = performance.now();
    resolveReady();
  },
  (e) => {
    fail(e);
    rejectReady(e instanceof Error ? e : new Error(String(e)));
  },
);
