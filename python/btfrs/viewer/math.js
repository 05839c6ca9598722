// Small vector and matrix helpers of the viewer. Matrices are Float32Array(16), column-major,
// as WGSL's mat4x4<f32> reads them. The camera is glam's (the native renderer's): right-handed,
// depth in [0, 1].

export function vec3Sub(a, b) {
  return [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
}

export function vec3Add(a, b) {
  return [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
}

export function vec3Scale(a, s) {
  return [a[0] * s, a[1] * s, a[2] * s];
}

export function vec3Dot(a, b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

export function vec3Cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}

export function vec3Length(a) {
  return Math.sqrt(vec3Dot(a, a));
}

export function vec3Normalize(a) {
  const n = vec3Length(a);
  return n > 0 ? [a[0] / n, a[1] / n, a[2] / n] : [0, 0, 0];
}

// Product of two column-major 4x4 matrices: a * b.
export function mat4Mul(a, b) {
  const out = new Float32Array(16);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      out[c * 4 + r] = s;
    }
  }
  return out;
}

// glam's Mat4::perspective_rh: depth 0 at near, 1 at far.
export function perspectiveRh(fovYRadians, aspect, near, far) {
  const f = 1 / Math.tan(fovYRadians / 2);
  const r = far / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, r, -1, 0, 0, r * near, 0]);
}

// glam's Mat4::look_at_rh.
export function lookAtRh(eye, target, up) {
  const f = vec3Normalize(vec3Sub(target, eye));
  const s = vec3Normalize(vec3Cross(f, up));
  const u = vec3Cross(s, f);
  return new Float32Array([
    s[0], u[0], -f[0], 0,
    s[1], u[1], -f[1], 0,
    s[2], u[2], -f[2], 0,
    -vec3Dot(s, eye), -vec3Dot(u, eye), vec3Dot(f, eye), 1,
  ]);
}

// sin of the angle under which two directions count as parallel (the native camera's).
const PARALLEL_SIN = 1e-4;

export function isParallel(a, b) {
  return vec3Length(vec3Cross(vec3Normalize(a), vec3Normalize(b))) <= PARALLEL_SIN;
}

// The native Camera::view_proj: an up parallel to the view direction falls back to +y (+z when
// the view runs along y).
export function cameraViewProj(camera, aspect) {
  const dir = vec3Sub(camera.target, camera.eye);
  let up = camera.up;
  if (isParallel(dir, up)) up = isParallel(dir, [0, 1, 0]) ? [0, 0, 1] : [0, 1, 0];
  const proj = perspectiveRh((camera.fov * Math.PI) / 180, aspect, camera.near, camera.far);
  return mat4Mul(proj, lookAtRh(camera.eye, camera.target, up));
}

// The exact piecewise sRGB encoding of a linear value in [0, 1] (the display pass's curve).
export function srgbEncode(x) {
  return x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055;
}

// A light direction from a point of the unit disc (the RTI habit): (x, y) clamped to the disc,
// z = sqrt(1 - x^2 - y^2).
export function discToLight(x, y) {
  const r = Math.hypot(x, y);
  if (r > 1) {
    x /= r;
    y /= r;
  }
  return [x, y, Math.sqrt(Math.max(0, 1 - x * x - y * y))];
}

// The camera orbited around its target: `dAzimuth` about the up axis, `dElevation` towards it
// (kept short of the pole), the distance multiplied by `zoom`.
export function orbitCamera(camera, dAzimuth, dElevation, zoom) {
  const up = vec3Normalize(camera.up);
  const off = vec3Sub(camera.eye, camera.target);
  let dist = vec3Length(off);
  // A frame around `up`: two horizontal axes.
  let h0 = vec3Cross(up, [1, 0, 0]);
  if (vec3Length(h0) < 1e-3) h0 = vec3Cross(up, [0, 1, 0]);
  h0 = vec3Normalize(h0);
  const h1 = vec3Cross(up, h0);
  const height = vec3Dot(off, up);
  const horiz = [vec3Dot(off, h0), vec3Dot(off, h1)];
  let az = Math.atan2(horiz[1], horiz[0]) + dAzimuth;
  const limit = (89 * Math.PI) / 180;
  let el = Math.atan2(height, Math.hypot(horiz[0], horiz[1])) + dElevation;
  el = Math.max(-limit, Math.min(limit, el));
  dist = Math.max(1e-3, dist * zoom);
  const dirH = vec3Add(vec3Scale(h0, Math.cos(az)), vec3Scale(h1, Math.sin(az)));
  const o = vec3Add(vec3Scale(dirH, dist * Math.cos(el)), vec3Scale(up, dist * Math.sin(el)));
  return { ...camera, eye: vec3Add(camera.target, o) };
}

// The camera moved in its image plane by (dx, dy) times its distance (eye and target together),
// the distance multiplied by `zoom`.
export function panCamera(camera, dx, dy, zoom) {
  const fwd = vec3Normalize(vec3Sub(camera.target, camera.eye));
  let up = camera.up;
  if (isParallel(fwd, up)) up = isParallel(fwd, [0, 1, 0]) ? [0, 0, 1] : [0, 1, 0];
  const right = vec3Normalize(vec3Cross(fwd, up));
  const upv = vec3Cross(right, fwd);
  const dist = vec3Length(vec3Sub(camera.eye, camera.target));
  const move = vec3Add(vec3Scale(right, -dx * dist), vec3Scale(upv, dy * dist));
  const target = vec3Add(camera.target, move);
  const eye = vec3Add(target, vec3Scale(fwd, -Math.max(1e-3, dist * zoom)));
  return { ...camera, eye, target };
}
