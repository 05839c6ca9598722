// The viewer's page: the canvas, the model's facts, the scene selector, the exposure slider, the
// light-direction disc and, in the 2D view, the rendering mode and its parameters, with the
// pointer interactions on the image.

import { discToLight } from "./math.js";

function uiElement(tag, attrs, parent) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "text") e.textContent = v;
    else e.setAttribute(k, v);
  }
  if (parent) parent.appendChild(e);
  return e;
}

function uiBytes(n) {
  if (n >= 1048576) return `${(n / 1048576).toFixed(1)} MiB`;
  if (n >= 1024) return `${(n / 1024).toFixed(1)} KiB`;
  return `${n} B`;
}

const SVG_NS = "http://www.w3.org/2000/svg";

function uiSvg(tag, attrs, parent) {
  const e = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
  parent.appendChild(e);
  return e;
}

// The light disc (SVG): the unit disc seen from above, +x right, +y up, and the light's (x, y);
// a drag sets it.
function uiLightDisc(parent, onLight) {
  const disc = uiSvg("svg", { id: "light-disc", viewBox: "-1.1 -1.1 2.2 2.2", width: 140, height: 140,
    role: "slider", "aria-label": "Light direction: drag" }, parent);
  uiSvg("circle", { cx: 0, cy: 0, r: 1, fill: "#222", stroke: "#666", "stroke-width": 0.02 }, disc);
  uiSvg("path", { d: "M -1 0 H 1 M 0 -1 V 1", stroke: "#555", "stroke-width": 0.015 }, disc);
  uiSvg("circle", { cx: 0, cy: 0, r: 0.5, fill: "none", stroke: "#444", "stroke-width": 0.015 }, disc);
  const dot = uiSvg("circle", { cx: 0, cy: 0, r: 0.08, fill: "#fc3", stroke: "#000", "stroke-width": 0.02 }, disc);
  function fromEvent(ev) {
    const rect = disc.getBoundingClientRect();
    const x = ((ev.clientX - rect.left) / rect.width) * 2.2 - 1.1;
    const y = 1.1 - ((ev.clientY - rect.top) / rect.height) * 2.2;
    onLight(discToLight(x, y));
  }
  let dragging = false;
  disc.addEventListener("pointerdown", (ev) => {
    dragging = true;
    disc.setPointerCapture(ev.pointerId);
    fromEvent(ev);
  });
  disc.addEventListener("pointermove", (ev) => {
    if (dragging) fromEvent(ev);
  });
  const stop = (ev) => {
    if (dragging) {
      dragging = false;
      if (disc.hasPointerCapture(ev.pointerId)) disc.releasePointerCapture(ev.pointerId);
    }
  };
  disc.addEventListener("pointerup", stop);
  disc.addEventListener("pointercancel", stop);
  return {
    set(l) {
      dot.setAttribute("cx", String(l[0]));
      dot.setAttribute("cy", String(-l[1]));
    },
  };
}

// The 2D view's modes as the page names them, and their parameters' sliders.
const MODE_NAMES = { default: "Default", diffuse_gain: "Diffuse gain", specular: "Specular enhancement", normals: "Normal map" };
const PARAMS = {
  gain: { label: "Gain", min: 1, max: 10, step: 0.1, modes: ["diffuse_gain"] },
  kd: { label: "Diffuse (kd)", min: 0, max: 1, step: 0.01, modes: ["specular"] },
  ks: { label: "Specular (ks)", min: 0, max: 2, step: 0.01, modes: ["specular"] },
  exponent: { label: "Exponent", min: 1, max: 200, step: 1, modes: ["specular"] },
};

// Build the page under `root`. `on` holds the callbacks: light(dir), scene(name),
// exposure(value), orbit(dxPixels, dyPixels, rect), zoom(factor, [x, y] canvas pixels),
// imageLight(x, y in [-1, 1]), mode(name), modeParam(name, value).
export function buildUi(root, on) {
  const header = uiElement("header", {}, root);
  uiElement("h1", { text: "btfrs viewer" }, header);
  const facts = uiElement("p", { id: "facts", text: "loading the model..." }, header);
  const message = uiElement("div", { id: "message", role: "alert", hidden: "" }, root);
  const main = uiElement("main", {}, root);
  // The canvas sits in a stage that takes the pointer events, so that it can be replaced (a
  // canvas keeps the first kind of context it gives: WebGPU or 2D).
  const stage = uiElement("div", { id: "stage", tabindex: "0" }, main);
  let canvas = uiElement("canvas", { id: "view", width: 512, height: 512 }, stage);
  const panel = uiElement("aside", {}, main);

  const sceneLabel = uiElement("label", { text: "Scene " }, panel);
  const sceneSelect = uiElement("select", { id: "scene" }, sceneLabel);
  sceneSelect.addEventListener("change", () => on.scene(sceneSelect.value));

  const expLabel = uiElement("label", { text: "Exposure " }, panel);
  const exposure = uiElement("input", { id: "exposure", type: "range", min: "-4", max: "4", step: "0.05", value: "0" }, expLabel);
  const expValue = uiElement("output", { id: "exposure-value", text: "1.00" }, expLabel);
  exposure.addEventListener("input", () => on.exposure(Math.pow(2, Number(exposure.value))));

  const modeLabel = uiElement("label", { text: "Mode " }, panel);
  const modeSelect = uiElement("select", { id: "mode" }, modeLabel);
  for (const [k, v] of Object.entries(MODE_NAMES)) uiElement("option", { value: k, text: v }, modeSelect);
  modeSelect.addEventListener("change", () => on.mode(modeSelect.value));
  const params = {};
  for (const [k, p] of Object.entries(PARAMS)) {
    const label = uiElement("label", { text: `${p.label} ` }, panel);
    const input = uiElement("input", { id: k, type: "range", min: String(p.min), max: String(p.max), step: String(p.step) }, label);
    const out = uiElement("output", { id: `${k}-value` }, label);
    input.addEventListener("input", () => on.modeParam(k, Number(input.value)));
    params[k] = { label, input, out };
  }

  const skyLabel = uiElement("label", { text: "Sky light " }, panel);
  const sky = uiElement("input", { id: "sky", type: "checkbox" }, skyLabel);
  sky.addEventListener("change", () => on.sky(sky.checked));

  uiElement("div", { class: "caption", text: "Light direction" }, panel);
  const disc = uiLightDisc(panel, (l) => on.light(l));
  const lightText = uiElement("div", { id: "light-value", class: "caption" }, panel);
  const help = uiElement("p", { class: "help" }, panel);

  // Pointer on the image: orbit (or pan), or with L held, the light.
  let lHeld = false;
  window.addEventListener("keydown", (ev) => {
    if (ev.key === "l" || ev.key === "L") lHeld = true;
  });
  window.addEventListener("keyup", (ev) => {
    if (ev.key === "l" || ev.key === "L") lHeld = false;
  });
  window.addEventListener("blur", () => {
    lHeld = false;
  });
  let last = null;
  function imageLight(ev) {
    const rect = canvas.getBoundingClientRect();
    on.imageLight(((ev.clientX - rect.left) / rect.width) * 2 - 1, 1 - ((ev.clientY - rect.top) / rect.height) * 2);
  }
  stage.addEventListener("pointerdown", (ev) => {
    stage.setPointerCapture(ev.pointerId);
    last = [ev.clientX, ev.clientY];
    if (lHeld) imageLight(ev);
  });
  stage.addEventListener("pointermove", (ev) => {
    if (!last) return;
    if (lHeld) {
      imageLight(ev);
    } else {
      on.orbit(ev.clientX - last[0], ev.clientY - last[1], canvas.getBoundingClientRect());
    }
    last = [ev.clientX, ev.clientY];
  });
  const stop = (ev) => {
    last = null;
    if (stage.hasPointerCapture(ev.pointerId)) stage.releasePointerCapture(ev.pointerId);
  };
  stage.addEventListener("pointerup", stop);
  stage.addEventListener("pointercancel", stop);
  stage.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const rect = canvas.getBoundingClientRect();
    const at = rect.width > 0 && rect.height > 0
      ? [((ev.clientX - rect.left) * canvas.width) / rect.width, ((ev.clientY - rect.top) * canvas.height) / rect.height]
      : null;
    on.zoom(Math.exp(Math.max(-1, Math.min(1, ev.deltaY * 0.001))), at);
  }, { passive: false });

  return {
    get canvas() {
      return canvas;
    },
    // A fresh canvas in place of the current one.
    newCanvas() {
      const c = uiElement("canvas", { id: "view", width: canvas.width, height: canvas.height, class: canvas.className });
      canvas.replaceWith(c);
      canvas = c;
      return c;
    },
    showMessage(text) {
      message.textContent = text;
      message.hidden = !text;
    },
    setFacts(info) {
      facts.textContent = `${info.kind} model "${info.name}", ${info.size[0]} x ${info.size[1]} texels, ` +
        `${uiBytes(info.bytes)}${info.surface ? `, ${info.surface}` : ""} (${info.adapter})`;
    },
    setScenes(names, current) {
      sceneSelect.replaceChildren(...names.map((n) => uiElement("option", { value: n, text: n })));
      sceneSelect.value = current;
    },
    setScene(name) {
      sceneSelect.value = name;
    },
    setSky(on, available) {
      sky.checked = on;
      skyLabel.hidden = !available;
    },
    setExposure(value) {
      exposure.value = String(Math.log2(value));
      expValue.textContent = value.toFixed(2);
    },
    setLight(l) {
      disc.set(l);
      lightText.textContent = `light (${l.map((x) => x.toFixed(2)).join(", ")})`;
    },
    setHelp(singleView, image) {
      help.textContent = (image
        ? "Drag on the image to pan, wheel to zoom (down to single texels). "
        : singleView
          ? "Drag on the image to pan, wheel to zoom (a single-view model: the camera does not orbit). "
          : "Drag on the image to orbit, wheel to zoom. ") +
        "Drag on the disc, or hold L and drag on the image, to move the light.";
    },
    // The mode and its parameters (shown in the 2D view only, each parameter with its mode); in
    // the 2D view the canvas fills the page (`fill`) or shows its pixels at their aspect.
    setMode(state, image, fill) {
      modeLabel.hidden = !image;
      modeSelect.value = state.mode;
      for (const [k, p] of Object.entries(PARAMS)) {
        params[k].label.hidden = !image || !p.modes.includes(state.mode);
        params[k].input.value = String(state[k]);
        params[k].out.textContent = Number(state[k]).toFixed(2);
      }
      canvas.classList.toggle("image", image);
      canvas.classList.toggle("fill", image && fill);
    },
  };
}
