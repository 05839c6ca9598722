// The WebGPU side of the viewer: the model's buffers and pipeline built from the manifest's
// layout (no offset or binding of its own), the frame drawn into an rgba32float target the
// viewer owns, then the display pass (exposure, clamp, sRGB) into an rgba8unorm texture the
// viewer owns, which is also drawn on the canvas, and read back from.

import { cameraViewProj } from "./math.js";
import { RTI_WGSL, RTI_SHOW_WGSL, RTI_UNIFORM_SIZE } from "./rti.js";

// The display pass: a full-screen triangle reading the linear frame with textureLoad.
const DISPLAY_WGSL = `
struct Display { exposure: f32, raw: f32, pad1: f32, pad2: f32 };
@group(0) @binding(0) var frame: texture_2d<f32>;
@group(0) @binding(1) var<uniform> display: Display;

@vertex
fn vs_display(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let p = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(p * 2.0 - 1.0, 0.0, 1.0);
}

fn srgb(x: f32) -> f32 {
    if (x <= 0.0031308) {
        return 12.92 * x;
    }
    return 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}

@fragment
fn fs_display(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let v = textureLoad(frame, vec2<i32>(pos.xy), 0);
    if (display.raw > 0.5) {
        // Values that are already display values (a normal map's (n + 1) / 2).
        return vec4<f32>(clamp(v.rgb, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
    }
    let c = clamp(v.rgb * display.exposure, vec3<f32>(0.0), vec3<f32>(1.0));
    return vec4<f32>(srgb(c.r), srgb(c.g), srgb(c.b), 1.0);
}
`;

const DISPLAY_FORMAT = "rgba8unorm";

// A uniform struct's fields by name, from the manifest: name -> byte offset.
function fieldOffsets(struct, what) {
  const out = {};
  for (const f of struct.fields) out[f.name] = f.offset;
  return new Proxy(out, {
    get(t, k) {
      if (typeof k === "string" && !(k in t)) throw new Error(`the manifest's ${what} layout has no field "${k}"`);
      return t[k];
    },
  });
}

function bindingLayoutEntry(b) {
  const visibility = GPUShaderStage.VERTEX | GPUShaderStage.FRAGMENT;
  switch (b.kind) {
    case "uniform":
      return { binding: b.binding, visibility, buffer: { type: "uniform" } };
    case "read-only-storage":
      return { binding: b.binding, visibility, buffer: { type: "read-only-storage" } };
    case "storage":
      return { binding: b.binding, visibility, buffer: { type: "storage" } };
    case "texture-3d":
      return { binding: b.binding, visibility, texture: { sampleType: b.sample_type, viewDimension: b.view_dimension } };
    case "texture-2d":
      return { binding: b.binding, visibility, texture: { sampleType: "float", viewDimension: "2d" } };
    case "sampler":
      return { binding: b.binding, visibility, sampler: { type: b.filter === "nearest" ? "non-filtering" : "filtering" } };
    default:
      throw new Error(`the manifest names a binding of unknown kind "${b.kind}" (${b.name})`);
  }
}

function bufferWith(device, bytes, usage, label) {
  const size = Math.max(4, Math.ceil(bytes.byteLength / 4) * 4);
  const buf = device.createBuffer({ label, size, usage: usage | GPUBufferUsage.COPY_DST });
  if (bytes.byteLength) {
    if (bytes.byteLength % 4 === 0) {
      device.queue.writeBuffer(buf, 0, bytes);
    } else {
      const padded = new Uint8Array(size);
      padded.set(new Uint8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength));
      device.queue.writeBuffer(buf, 0, padded);
    }
  }
  return buf;
}

// An adapter and a device able to hold the model's largest buffer in one binding. After a lost
// device (`afterLoss`) the browser may still be restarting its GPU process: requestAdapter then
// answers null for a moment, so it is asked again for up to 3 s before that counts as no adapter.
export async function openGpu(largestBuffer, afterLoss = false) {
  if (!("gpu" in navigator) || !navigator.gpu) {
    throw new Error("WebGPU is not available in this browser (navigator.gpu is missing): use a recent Chrome, Edge " +
      "or Firefox over https:// or http://localhost, or open the file from disk");
  }
  let adapter = await navigator.gpu.requestAdapter();
  for (let i = 0; !adapter && afterLoss && i < 12; i++) {
    await new Promise((r) => setTimeout(r, 250));
    adapter = await navigator.gpu.requestAdapter();
  }
  if (!adapter) throw new Error("WebGPU is present but no GPU adapter was found (requestAdapter returned null)");
  const need = Math.max(largestBuffer, 4);
  const limits = {};
  if (need > 134217728) {
    if (need > adapter.limits.maxStorageBufferBindingSize || need > adapter.limits.maxBufferSize) {
      throw new Error(`the model needs one storage buffer of ${(need / 1048576).toFixed(0)} MiB; this adapter binds ` +
        `at most ${(adapter.limits.maxStorageBufferBindingSize / 1048576).toFixed(0)} MiB`);
    }
    limits.maxStorageBufferBindingSize = need;
    limits.maxBufferSize = need;
  }
  const device = await adapter.requestDevice({ requiredLimits: limits });
  const info = adapter.info || {};
  const name = [info.vendor, info.architecture, info.description].filter((s) => s).join(" ") || "unknown adapter";
  return { adapter, device, adapterName: name };
}

// Compile a WGSL module and fail with its compiler messages (line:column) on error.
async function compiledModule(device, code, label) {
  const module = device.createShaderModule({ label, code });
  const info = await module.getCompilationInfo();
  const errors = info.messages.filter((m) => m.type === "error");
  if (errors.length) {
    const text = errors.map((m) => `${label}:${m.lineNum}:${m.linePos}: ${m.message}`).join("\n");
    throw new Error(`the shader does not compile in this browser:\n${text}`);
  }
  return module;
}

// The store's bytes: the model's store file, or for a tiled model a store laid out for a window
// (`tiles.store_words`) holding the parts every window shares (the store file, concatenated) at
// their offsets, its texel parts left for the window's tiles.
function storeBytes(manifest, files) {
  const t = manifest.tiles;
  const bytes = files[manifest.files.store];
  if (!t) return bytes;
  const out = new Uint8Array(t.store_words * 4);
  let at = 0;
  for (const c of t.constants) {
    out.set(bytes.subarray(at, at + c.words * 4), c.offset * 4);
    at += c.words * 4;
  }
  if (at !== bytes.byteLength) throw new Error(`model/${manifest.files.store}: ${bytes.byteLength} bytes; the manifest's parts take ${at}`);
  return out;
}

// Everything on the device for one model (`files`: name -> Uint8Array; `shaderCode`: the WGSL):
// `render(view)` draws a frame, `readPixels()` reads the last displayed frame back. The frame is
// shown on `canvas`: with `present` "webgpu" by a second draw into the canvas's own texture,
// with "2d" (where the browser cannot present a WebGPU canvas, as headless Chromium) by reading
// the frame back into a 2D canvas.
export async function createRenderer(gpu, manifest, files, shaderCode, canvas, present) {
  const device = gpu.device;
  const layout = manifest.layout;
  const G = fieldOffsets(layout.globals, "globals");
  const L = fieldOffsets(layout.light, "light");

  device.pushErrorScope("validation");
  // Group 0 and 1 layouts, from the manifest's bindings.
  const groupLayouts = [];
  const groupBindings = [];
  const groups = Object.keys(layout.bindings).map(Number).sort((a, b) => a - b);
  groups.forEach((g, i) => {
    if (g !== i) throw new Error(`the manifest's bind groups are not numbered 0, 1, ...: ${groups}`);
    const list = layout.bindings[String(g)];
    groupBindings.push(list);
    groupLayouts.push(device.createBindGroupLayout({ label: `btfrs group ${g}`, entries: list.map(bindingLayoutEntry) }));
  });

  const U = GPUBufferUsage;
  const globalsBuf = device.createBuffer({ label: "globals", size: layout.globals.size, usage: U.UNIFORM | U.COPY_DST });
  let lightsBuf = null;
  let lightsCap = 0;
  const resources = {
    globals: { buffer: globalsBuf },
    // The texture over the surface: a coordinate map or a Wang tile map, laid out by btfrs
    // (the words and their Globals fields are the manifest's), or one placeholder word.
    coord_map: { buffer: bufferWith(device, manifest.map ? files[manifest.map.file] : new Uint32Array([0]), U.STORAGE, "coord_map") },
    env: { buffer: bufferWith(device, new Float32Array(4), U.STORAGE, "env") },
    params: { buffer: bufferWith(device, files[manifest.files.params], U.UNIFORM, "params") },
    store: { buffer: bufferWith(device, storeBytes(manifest, files), U.STORAGE, "store") },
    dirs: { buffer: bufferWith(device, files[manifest.files.dirs], U.STORAGE, "dirs") },
    tables: { buffer: bufferWith(device, files[manifest.files.tables], U.STORAGE, "tables") },
  };
  // The optional 3D texture, a 1 x 1 x 1 placeholder otherwise.
  let volSize = [1, 1, 1];
  let volBytes = new Uint8Array(4);
  if (manifest.volume) {
    volSize = manifest.volume.size;
    volBytes = files[manifest.volume.file];
    if (manifest.volume.format && manifest.volume.format !== "rgba8unorm") {
      throw new Error(`the manifest's volume format ${manifest.volume.format} is not supported (rgba8unorm)`);
    }
  }
  const volume = device.createTexture({
    label: "volume", size: volSize, dimension: "3d", format: "rgba8unorm",
    usage: GPUTextureUsage.TEXTURE_BINDING | GPUTextureUsage.COPY_DST,
  });
  device.queue.writeTexture({ texture: volume }, volBytes, { bytesPerRow: volSize[0] * 4, rowsPerImage: volSize[1] }, volSize);
  resources.volume = volume.createView({ dimension: "3d" });
  for (const b of groupBindings[1] || []) {
    if (b.kind === "sampler") {
      const filter = b.filter || "linear";
      const address = b.address || "clamp-to-edge";
      resources[b.name] = device.createSampler({
        label: b.name, magFilter: filter, minFilter: filter, mipmapFilter: "nearest",
        addressModeU: address, addressModeV: address, addressModeW: address,
      });
    }
  }

  const modelGroup = device.createBindGroup({
    label: "btfrs model",
    layout: groupLayouts[1],
    entries: groupBindings[1].map((b) => {
      if (!(b.name in resources)) throw new Error(`the manifest's binding "${b.name}" (group 1) is unknown to this viewer`);
      return { binding: b.binding, resource: resources[b.name] };
    }),
  });

  // Scenes: vertex and index buffers, made on first use.
  const sceneBufs = {};
  function sceneBuffers(name) {
    if (!sceneBufs[name]) {
      const s = manifest.scenes[name];
      if (!s) throw new Error(`unknown scene "${name}" (the model has ${Object.keys(manifest.scenes).join(", ")})`);
      sceneBufs[name] = {
        vertices: bufferWith(device, files[s.vertices], U.VERTEX, `${name} vertices`),
        indices: bufferWith(device, files[s.indices], U.INDEX, `${name} indices`),
        count: s.index_count,
      };
    }
    return sceneBufs[name];
  }

  // The model's pipeline, exactly as the native renderer builds it; with the 2D view's entry
  // points appended for a single-view model (rti.js).
  const code = manifest.rti ? shaderCode + RTI_WGSL : shaderCode;
  const module = await compiledModule(device, code, `${manifest.model.kind}.wgsl`);
  const vtx = layout.vertex;
  const targets = layout.targets;
  const pipeline = await device.createRenderPipelineAsync({
    label: `btfrs ${manifest.model.kind}`,
    layout: device.createPipelineLayout({ bindGroupLayouts: groupLayouts }),
    vertex: {
      module,
      entryPoint: layout.entry.vertex,
      buffers: [{
        arrayStride: vtx.stride,
        stepMode: "vertex",
        attributes: vtx.attributes.map((a) => ({ shaderLocation: a.location, offset: a.offset, format: a.format })),
      }],
    },
    primitive: { topology: "triangle-list", cullMode: targets.cull || "none" },
    depthStencil: { format: targets.depth, depthWriteEnabled: true, depthCompare: targets.depth_compare },
    fragment: { module, entryPoint: layout.entry.fragment, targets: [{ format: targets.color }] },
  });

  // The 2D view's pipelines, each a full-screen triangle with the view's uniform block in
  // group 2: in one pass, each pixel bilinear between four texels the model relights
  // (minified views); in two, the texels under the canvas relit once each into a float
  // texture, then each pixel bilinear between four of them (magnified views: a texel relit
  // once, not once per pixel it covers).
  let rti = null;
  if (manifest.rti) {
    const vis = GPUShaderStage.VERTEX | GPUShaderStage.FRAGMENT;
    const buf = device.createBuffer({ label: "rti", size: RTI_UNIFORM_SIZE, usage: U.UNIFORM | U.COPY_DST });
    const layout2 = device.createBindGroupLayout({ label: "rti", entries: [{ binding: 0, visibility: vis, buffer: { type: "uniform" } }] });
    const group = device.createBindGroup({ label: "rti", layout: layout2, entries: [{ binding: 0, resource: { buffer: buf } }] });
    const pipelineLayout = device.createPipelineLayout({ bindGroupLayouts: [...groupLayouts, layout2] });
    const direct = await device.createRenderPipelineAsync({
      label: `btfrs ${manifest.model.kind} 2D`,
      layout: pipelineLayout,
      vertex: { module, entryPoint: "vs_rti" },
      primitive: { topology: "triangle-list" },
      depthStencil: { format: targets.depth, depthWriteEnabled: false, depthCompare: "always" },
      fragment: { module, entryPoint: "fs_rti", targets: [{ format: targets.color }] },
    });
    const relight = await device.createRenderPipelineAsync({
      label: `btfrs ${manifest.model.kind} 2D texels`,
      layout: pipelineLayout,
      vertex: { module, entryPoint: "vs_rti" },
      primitive: { topology: "triangle-list" },
      fragment: { module, entryPoint: "fs_rti_texels", targets: [{ format: "rgba32float" }] },
    });
    const showModule = await compiledModule(device, RTI_SHOW_WGSL, "rti_show.wgsl");
    const showLayout = device.createBindGroupLayout({
      label: "rti show",
      entries: [
        { binding: 0, visibility: vis, buffer: { type: "uniform" } },
        { binding: 1, visibility: GPUShaderStage.FRAGMENT, texture: { sampleType: "unfilterable-float" } },
      ],
    });
    const show = await device.createRenderPipelineAsync({
      label: "btfrs 2D show",
      layout: device.createPipelineLayout({ bindGroupLayouts: [showLayout] }),
      vertex: { module: showModule, entryPoint: "vs_show" },
      primitive: { topology: "triangle-list" },
      depthStencil: { format: targets.depth, depthWriteEnabled: false, depthCompare: "always" },
      fragment: { module: showModule, entryPoint: "fs_show", targets: [{ format: targets.color }] },
    });
    rti = { buf, group, direct, relight, show, showLayout, values: null, showGroup: null };
  }

  // The float texture the two-pass view relights its texels into (kept, grown as needed).
  function valuesFor(w, h) {
    const v = rti.values;
    if (v && v.width >= w && v.height >= h) return v;
    if (v) v.destroy();
    const size = [Math.max(w, v ? v.width : 0), Math.max(h, v ? v.height : 0)].map((x) => Math.ceil(x / 64) * 64);
    rti.values = device.createTexture({ label: "rti values", size, format: "rgba32float",
      usage: GPUTextureUsage.RENDER_ATTACHMENT | GPUTextureUsage.TEXTURE_BINDING });
    rti.showGroup = device.createBindGroup({
      label: "rti show",
      layout: rti.showLayout,
      entries: [{ binding: 0, resource: { buffer: rti.buf } }, { binding: 1, resource: rti.values.createView() }],
    });
    return rti.values;
  }

  // The display pipelines: into the owned rgba8unorm texture and into the canvas.
  const displayModule = await compiledModule(device, DISPLAY_WGSL, "display.wgsl");
  const displayLayout = device.createBindGroupLayout({
    label: "display",
    entries: [
      { binding: 0, visibility: GPUShaderStage.FRAGMENT, texture: { sampleType: "unfilterable-float" } },
      { binding: 1, visibility: GPUShaderStage.FRAGMENT, buffer: { type: "uniform" } },
    ],
  });
  const displayPipes = {};
  function displayPipeline(format) {
    if (!displayPipes[format]) {
      displayPipes[format] = device.createRenderPipeline({
        label: `display ${format}`,
        layout: device.createPipelineLayout({ bindGroupLayouts: [displayLayout] }),
        vertex: { module: displayModule, entryPoint: "vs_display" },
        fragment: { module: displayModule, entryPoint: "fs_display", targets: [{ format }] },
        primitive: { topology: "triangle-list" },
      });
    }
    return displayPipes[format];
  }
  const displayBuf = device.createBuffer({ label: "display", size: 16, usage: U.UNIFORM | U.COPY_DST });

  let context = null;
  let canvasFormat = null;
  let context2d = null;
  if (canvas && present === "webgpu") {
    context = canvas.getContext("webgpu");
    if (!context) throw new Error("the canvas has no WebGPU context");
    canvasFormat = navigator.gpu.getPreferredCanvasFormat();
    context.configure({ device, format: canvasFormat, alphaMode: "opaque" });
    displayPipeline(canvasFormat);
  } else if (canvas) {
    context2d = canvas.getContext("2d");
  }
  displayPipeline(DISPLAY_FORMAT);
  const err = await device.popErrorScope();
  if (err) throw new Error(`WebGPU refused the viewer's setup: ${err.message}`);

  // Targets, remade when the size changes.
  let tex = null;
  function targetsFor(w, h) {
    if (tex && tex.w === w && tex.h === h) return tex;
    if (tex) {
      tex.color.destroy();
      tex.depth.destroy();
      tex.display.destroy();
    }
    const T = GPUTextureUsage;
    const color = device.createTexture({ label: "frame", size: [w, h], format: targets.color, usage: T.RENDER_ATTACHMENT | T.TEXTURE_BINDING });
    const depth = device.createTexture({ label: "depth", size: [w, h], format: targets.depth, usage: T.RENDER_ATTACHMENT });
    const display = device.createTexture({ label: "display", size: [w, h], format: DISPLAY_FORMAT, usage: T.RENDER_ATTACHMENT | T.COPY_SRC });
    const displayGroup = device.createBindGroup({
      layout: displayLayout,
      entries: [{ binding: 0, resource: color.createView() }, { binding: 1, resource: { buffer: displayBuf } }],
    });
    tex = { w, h, color, depth, display, displayGroup };
    return tex;
  }

  function writeGlobals(view, nLights) {
    const data = new ArrayBuffer(layout.globals.size);
    const f = new Float32Array(data);
    const u = new Uint32Array(data);
    // The 2D view has no camera: its own pass maps pixels to texels.
    if (view.camera) {
      f.set(cameraViewProj(view.camera, view.width / view.height), G.view_proj / 4);
      f.set([view.camera.eye[0], view.camera.eye[1], view.camera.eye[2], 1], G.eye / 4);
    }
    f.set(manifest.uv_scale || [1, 1], G.uv_scale / 4);
    u.set(view.sampleSize || [manifest.model.width, manifest.model.height], G.sample_size / 4);
    const map = manifest.map;
    u.set(map ? map.map_size : [0, 0], G.map_size / 4);
    u[G.n_lights / 4] = nLights;
    u[G.chunk_len / 4] = manifest.chunk_len;
    u.set(map ? map.tiles : [0, 0, 0, 0], G.tiles / 4);
    u.set(map ? map.tile_atlas : [0, 0, 0, 0], G.tile_atlas / 4);
    u.set([0, 0, 0, 0], G.lookup / 4);
    device.queue.writeBuffer(globalsBuf, 0, data);
  }

  let frameGroup = null;
  function writeLights(lights) {
    const n = Math.max(1, lights.length);
    if (!lightsBuf || lightsCap < n) {
      if (lightsBuf) lightsBuf.destroy();
      lightsCap = n;
      lightsBuf = device.createBuffer({ label: "lights", size: n * layout.light.size, usage: U.STORAGE | U.COPY_DST });
      resources.lights = { buffer: lightsBuf };
      frameGroup = device.createBindGroup({
        label: "btfrs frame",
        layout: groupLayouts[0],
        entries: groupBindings[0].map((b) => {
          if (!(b.name in resources)) throw new Error(`the manifest's binding "${b.name}" (group 0) is unknown to this viewer`);
          return { binding: b.binding, resource: resources[b.name] };
        }),
      });
    }
    const data = new ArrayBuffer(n * layout.light.size);
    const f = new Float32Array(data);
    lights.forEach((l, i) => {
      const base = (i * layout.light.size) / 4;
      f.set([l.direction[0], l.direction[1], l.direction[2], 0], base + L.pos / 4);
      f.set([l.intensity[0], l.intensity[1], l.intensity[2], 0], base + L.intensity / 4);
    });
    device.queue.writeBuffer(lightsBuf, 0, data);
  }

  // Bytes of the window's texels into the store (a tiled model's window, at word `offset`).
  function writeStore(offset, bytes) {
    device.queue.writeBuffer(resources.store.buffer, offset * 4, bytes);
  }

  // One frame: view = {camera, lights: [{direction (unit, towards the light), intensity}],
  // scene, exposure, width, height}, or for the 2D view {image: RtiView bytes, sampleSize: the
  // window's [width, height], raw: display values as they are, exposure, width, height}.
  // Resolves when the GPU has finished it.
  async function render(view) {
    const t0 = performance.now();
    device.pushErrorScope("validation");
    const t = targetsFor(view.width, view.height);
    writeGlobals(view, view.image ? 0 : view.lights.length);
    writeLights(view.image ? [] : view.lights);
    device.queue.writeBuffer(displayBuf, 0, new Float32Array([view.exposure, view.raw ? 1 : 0, 0, 0]));
    if (view.image) device.queue.writeBuffer(rti.buf, 0, view.image);
    const s = view.image ? null : sceneBuffers(view.scene);
    const clear = targets.clear || [0, 0, 0, 1];
    const enc = device.createCommandEncoder({ label: "frame" });
    if (view.image && view.texels) {
      // The texels first, into the values texture (its top-left corner).
      const values = valuesFor(view.texels.w, view.texels.h);
      const rp = enc.beginRenderPass({
        colorAttachments: [{ view: values.createView(), loadOp: "clear", storeOp: "store", clearValue: { r: 0, g: 0, b: 0, a: 1 } }],
      });
      rp.setViewport(0, 0, view.texels.w, view.texels.h, 0, 1);
      rp.setScissorRect(0, 0, view.texels.w, view.texels.h);
      rp.setPipeline(rti.relight);
      rp.setBindGroup(0, frameGroup);
      rp.setBindGroup(1, modelGroup);
      rp.setBindGroup(2, rti.group);
      rp.draw(3);
      rp.end();
    }
    const pass = enc.beginRenderPass({
      colorAttachments: [{ view: t.color.createView(), loadOp: "clear", storeOp: "store",
        clearValue: { r: clear[0], g: clear[1], b: clear[2], a: clear[3] } }],
      depthStencilAttachment: { view: t.depth.createView(), depthClearValue: 1, depthLoadOp: "clear", depthStoreOp: "store" },
    });
    if (view.image && view.texels) {
      pass.setPipeline(rti.show);
      pass.setBindGroup(0, rti.showGroup);
      pass.draw(3);
    } else if (view.image) {
      pass.setPipeline(rti.direct);
      pass.setBindGroup(0, frameGroup);
      pass.setBindGroup(1, modelGroup);
      pass.setBindGroup(2, rti.group);
      pass.draw(3);
    } else {
      pass.setPipeline(pipeline);
      pass.setBindGroup(0, frameGroup);
      pass.setBindGroup(1, modelGroup);
      pass.setVertexBuffer(0, s.vertices);
      pass.setIndexBuffer(s.indices, "uint32");
      pass.drawIndexed(s.count);
    }
    pass.end();
    // The model's pass is submitted and waited for alone: its time is what the native
    // renderer's draw time measures (the display pass below is the page's own).
    device.queue.submit([enc.finish()]);
    await device.queue.onSubmittedWorkDone();
    const drawMs = performance.now() - t0;
    const show = device.createCommandEncoder({ label: "display" });
    const targetsOut = [[t.display.createView(), DISPLAY_FORMAT]];
    if (context) {
      if (canvas.width !== view.width || canvas.height !== view.height) {
        canvas.width = view.width;
        canvas.height = view.height;
      }
      targetsOut.push([context.getCurrentTexture().createView(), canvasFormat]);
    }
    for (const [v, format] of targetsOut) {
      const dp = show.beginRenderPass({
        colorAttachments: [{ view: v, loadOp: "clear", storeOp: "store", clearValue: { r: 0, g: 0, b: 0, a: 1 } }],
      });
      dp.setPipeline(displayPipeline(format));
      dp.setBindGroup(0, t.displayGroup);
      dp.draw(3);
      dp.end();
    }
    device.queue.submit([show.finish()]);
    const err = await device.popErrorScope();
    if (err) throw new Error(`WebGPU refused the frame: ${err.message}`);
    await device.queue.onSubmittedWorkDone();
    const ms = performance.now() - t0;
    if (context2d) {
      const p = await readPixels();
      if (canvas.width !== p.width || canvas.height !== p.height) {
        canvas.width = p.width;
        canvas.height = p.height;
      }
      context2d.putImageData(new ImageData(new Uint8ClampedArray(p.bytes.buffer), p.width, p.height), 0, 0);
    }
    return { ms, drawMs };
  }

  // The last displayed frame, RGBA8, rows top first: {width, height, bytes (Uint8Array)}.
  async function readPixels() {
    if (!tex) throw new Error("no frame drawn yet");
    const { w, h, display } = tex;
    const row = Math.ceil((w * 4) / 256) * 256;
    const buf = device.createBuffer({ label: "read-back", size: row * h, usage: U.COPY_DST | U.MAP_READ });
    const enc = device.createCommandEncoder({ label: "read-back" });
    enc.copyTextureToBuffer({ texture: display }, { buffer: buf, bytesPerRow: row, rowsPerImage: h }, [w, h]);
    device.queue.submit([enc.finish()]);
    await buf.mapAsync(GPUMapMode.READ);
    const src = new Uint8Array(buf.getMappedRange());
    const out = new Uint8Array(w * h * 4);
    for (let y = 0; y < h; y++) out.set(src.subarray(y * row, y * row + w * 4), y * w * 4);
    buf.unmap();
    buf.destroy();
    return { width: w, height: h, bytes: out };
  }

  return { render, readPixels, writeStore };
}
