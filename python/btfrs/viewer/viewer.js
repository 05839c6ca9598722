// The btfrs viewer: loads a model exported by btfrs.web (model/manifest.json beside the page,
// or the JSON script element of the single-file export) and draws it with WebGPU using the
// project's own shader. `window.btfrsViewer` is its scripting interface (see below).

import { discToLight, orbitCamera, panCamera, vec3Normalize, vec3Length } from "./math.js";
import { openGpu, createRenderer } from "./gpu.js";
import { buildUi } from "./ui.js";
import { KNOWN_KINDS } from "./kinds.js";

const WEB_FORMAT = "btfrs-web";
const WEB_VERSION = 1;

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
  const base = new URL("model/", document.baseURI);
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
};
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

function currentView() {
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
  viewerUi.setSky(viewerState.sky, Boolean(viewerManifest && viewerManifest.environment));
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
    if (!(s.scene in viewerManifest.scenes)) {
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
  // {eye, target, up, fov}, scene, exposure, size [width, height]; resolves after the new frame.
  async set(settings) {
    await api.ready;
    applySettings(settings || {});
    return requestFrame();
  },
  // The current settings (light, intensity, camera, scene, exposure, size).
  state() {
    return JSON.parse(JSON.stringify(viewerState));
  },
  // Resolves when every frame asked for so far is drawn.
  async settled() {
    await api.ready;
    while (frameLoop) await frameLoop;
  },
  // The last frame, RGBA8, rows top first: {width, height, encoding: "base64", data}.
  async readPixels() {
    await api.settled();
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
  // A drag on the image: orbit around the target, or pan for a single-view model (its
  // appearance is known from one view only).
  orbit(dx, dy, rect) {
    if (!viewerRenderer || !rect.width || !rect.height) return;
    const c = viewerState.camera;
    if (viewerManifest.model.views === 1) {
      const k = (2 * Math.tan((c.fov * Math.PI) / 360)) / rect.height;
      viewerState.camera = panCamera(c, dx * k, dy * k, 1);
    } else {
      viewerState.camera = orbitCamera(c, (-dx / rect.width) * Math.PI, (dy / rect.height) * Math.PI, 1);
    }
    redraw();
  },
  zoom(factor) {
    if (!viewerRenderer) return;
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
  const largest = Math.max(...Object.values(files).map((f) => f.byteLength));
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
    try {
      const { ms, drawMs } = await renderer.render(currentView());
      // A lost device may only say so after the frame.
      await new Promise((r) => setTimeout(r, 0));
      if (lost) throw new Error(`the GPU device was lost: ${lost.message}`);
      current = true;
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
  viewerState.scene = "plane" in manifest.scenes ? "plane" : Object.keys(manifest.scenes)[0];
  viewerUi.setScenes(Object.keys(manifest.scenes), viewerState.scene);
  viewerUi.setSky(false, Boolean(manifest.environment));
  viewerUi.setHelp(manifest.model.views === 1);
  showState();
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
