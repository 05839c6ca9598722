// A model written in relight's or NeuralRTI's tiled layout, read tile by tile: each plane image
// is a Deep Zoom pyramid (`plane_0.dzi` + `plane_0_files/{level}/{col}_{row}.{jpg|png}`, level 0
// one tile, as OpenLIME's `deepzoom` layout numbers them), and the page fetches only the tiles
// of the level and the region it draws. The store of the window it draws is filled from the
// tiles' bytes as the manifest says (`tiles.texels`: per store part, the plane of each byte).

// Parse a .dzi descriptor: {format, tileSize, overlap, width, height}; an error naming `name`.
export function parseDzi(text, name) {
  const doc = new DOMParser().parseFromString(text, "application/xml");
  const root = doc.documentElement;
  if (!root || root.localName !== "Image" || doc.getElementsByTagName("parsererror").length) {
    throw new Error(`${name}: not a Deep Zoom descriptor (expected an <Image> element)`);
  }
  const size = Array.from(root.children).find((e) => e.localName === "Size");
  const int = (el, key) => {
    const v = el ? el.getAttribute(key) : null;
    if (v === null || !/^\s*\d+\s*$/.test(v)) throw new Error(`${name}: ${key}: expected an integer, got ${JSON.stringify(v)}`);
    return Number(v);
  };
  const format = (root.getAttribute("Format") || "").toLowerCase();
  if (!["jpg", "jpeg", "png"].includes(format)) throw new Error(`${name}: Format: expected jpg or png, got ${JSON.stringify(format)}`);
  return { format, tileSize: int(root, "TileSize"), overlap: int(root, "Overlap"), width: int(size, "Width"),
    height: int(size, "Height") };
}

// OpenLIME's level count: the smallest k + 1 with max(width, height) <= tile * 2^k.
export function levelCount(width, height, tile) {
  let k = 0;
  while (tile * 2 ** k < Math.max(width, height)) k++;
  return k + 1;
}

// Decode an image to RGBA bytes exactly as stored (no colour management, no premultiplication).
async function decodeImage(blob) {
  const bmp = await createImageBitmap(blob, { colorSpaceConversion: "none", premultiplyAlpha: "none" });
  const canvas = new OffscreenCanvas(bmp.width, bmp.height);
  const ctx = canvas.getContext("2d", { willReadFrequently: true });
  ctx.drawImage(bmp, 0, 0);
  const data = ctx.getImageData(0, 0, bmp.width, bmp.height).data;
  const out = { width: bmp.width, height: bmp.height, data };
  bmp.close();
  return out;
}

// The tiles of a manifest's `tiles` block under `base` (a URL of the model's folder).
export async function openTiles(base, manifest, onLoaded) {
  const t = manifest.tiles;
  const dzis = await Promise.all(t.images.map(async (name) => {
    const r = await fetch(new URL(name, base));
    if (!r.ok) throw new Error(`cannot load model/${name} (HTTP ${r.status})`);
    return parseDzi(await r.text(), `model/${name}`);
  }));
  const d0 = dzis[0];
  dzis.forEach((d, i) => {
    const same = d.width === manifest.model.width && d.height === manifest.model.height && d.tileSize === d0.tileSize &&
      d.overlap === d0.overlap && d.format === d0.format;
    if (!same) {
      throw new Error(`model/${t.images[i]}: ${d.width} x ${d.height} pixels in ${d.tileSize}-pixel ${d.format} tiles; the ` +
        `model is ${manifest.model.width} x ${manifest.model.height} in ${d0.tileSize}-pixel ${d0.format} tiles`);
    }
  });
  const levels = levelCount(d0.width, d0.height, d0.tileSize);
  if (t.levels && t.levels !== levels) {
    throw new Error(`model/${t.images[0]} makes ${levels} levels of tiles; model/${t.index} declares ${t.levels}`);
  }
  return new TileSource(base, t, d0, levels, onLoaded);
}

class TileSource {
  constructor(base, tiles, dzi, levels, onLoaded) {
    this.base = base;
    this.images = tiles.images.map((n) => n.replace(/\.dzi$/, ""));
    this.parts = tiles.texels;
    this.capacity = tiles.capacity;
    this.width = dzi.width;
    this.height = dzi.height;
    this.tile = dzi.tileSize;
    this.overlap = dzi.overlap;
    this.format = dzi.format;
    this.levels = levels;
    this.onLoaded = onLoaded;
    // key "level/col_row" -> {state: "loading" | "loaded", images: [{width, height, data}], x0, y0}
    this.cache = new Map();
    // Every tile URL requested, in order (the page's request log).
    this.requested = [];
    this.pendingCount = 0;
    this.idleWaiters = [];
    this.error = null;
  }

  levelSize(level) {
    const s = this.levels - 1 - level;
    return [Math.max(1, Math.floor(this.width / 2 ** s)), Math.max(1, Math.floor(this.height / 2 ** s))];
  }

  // Tiles (col, row) of `level` under the window {x0, y0, w, h} (level texels).
  tilesOf(level, win) {
    const out = [];
    const t = this.tile;
    for (let r = Math.floor(win.y0 / t); r <= Math.floor((win.y0 + win.h - 1) / t); r++) {
      for (let c = Math.floor(win.x0 / t); c <= Math.floor((win.x0 + win.w - 1) / t); c++) out.push([c, r]);
    }
    return out;
  }

  // The pixels [x0, x1) x [y0, y1) a tile's image holds (Deep Zoom's overlap convention).
  rect(level, c, r) {
    const [w, h] = this.levelSize(level);
    const t = this.tile;
    const o = this.overlap;
    return [Math.max(0, c * t - o), Math.max(0, r * t - o), Math.min(w, (c + 1) * t + o), Math.min(h, (r + 1) * t + o)];
  }

  loaded(level, win) {
    return this.tilesOf(level, win).every(([c, r]) => {
      const e = this.cache.get(`${level}/${c}_${r}`);
      return e && e.state === "loaded";
    });
  }

  // Fetch the tiles of the window not yet asked for; `onLoaded` runs as each arrives.
  request(level, win) {
    for (const [c, r] of this.tilesOf(level, win)) {
      const key = `${level}/${c}_${r}`;
      if (this.cache.has(key)) continue;
      const entry = { state: "loading", images: null };
      this.cache.set(key, entry);
      this.pendingCount++;
      const urls = this.images.map((name) => `${name}_files/${level}/${c}_${r}.${this.format}`);
      this.requested.push(...urls);
      const [x0, y0, x1, y1] = this.rect(level, c, r);
      Promise.all(urls.map(async (u) => {
        const res = await fetch(new URL(u, this.base));
        if (!res.ok) throw new Error(`cannot load model/${u} (HTTP ${res.status})`);
        const img = await decodeImage(await res.blob());
        if (img.width !== x1 - x0 || img.height !== y1 - y0) {
          throw new Error(`model/${u}: ${img.width} x ${img.height} pixels; tile (${c}, ${r}) of level ${level} is ` +
            `${x1 - x0} x ${y1 - y0}`);
        }
        return img;
      })).then((images) => {
        Object.assign(entry, { state: "loaded", images, x0, y0, x1, y1 });
      }, (e) => {
        entry.state = "failed";
        if (!this.error) this.error = e;
      }).finally(() => {
        this.pendingCount--;
        this.onLoaded(this.error);
        if (this.pendingCount === 0) {
          const w = this.idleWaiters;
          this.idleWaiters = [];
          w.forEach((f) => f());
        }
      });
    }
  }

  pending() {
    return this.pendingCount;
  }

  // Resolves when no tile is being fetched.
  idle() {
    if (this.pendingCount === 0) return Promise.resolve();
    return new Promise((r) => this.idleWaiters.push(r));
  }

  // The window's bytes per store part (texel-major, the part's bytes per texel, padded to
  // words), from the loaded tiles: byte j of a texel is plane from[j], channel from[j] % 3 of
  // image from[j] / 3.
  assemble(level, win) {
    const out = this.parts.map((p) => new Uint8Array(Math.ceil((win.w * win.h * p.bytes) / 4) * 4));
    const x1w = win.x0 + win.w;
    const y1w = win.y0 + win.h;
    for (const [c, r] of this.tilesOf(level, win)) {
      const e = this.cache.get(`${level}/${c}_${r}`);
      if (!e || e.state !== "loaded") throw new Error(`tile (${c}, ${r}) of level ${level} is not loaded`);
      const tw = e.x1 - e.x0;
      // The tile's own pixels within the window (its overlap belongs to its neighbours).
      const ox0 = Math.max(win.x0, c * this.tile);
      const oy0 = Math.max(win.y0, r * this.tile);
      const ox1 = Math.min(x1w, (c + 1) * this.tile, e.x1);
      const oy1 = Math.min(y1w, (r + 1) * this.tile, e.y1);
      this.parts.forEach((p, pi) => {
        const R = p.bytes;
        const dst = out[pi];
        const src = p.from.map((pl) => e.images[Math.floor(pl / 3)].data);
        const ch = p.from.map((pl) => pl % 3);
        for (let y = oy0; y < oy1; y++) {
          let t = (y - win.y0) * win.w + (ox0 - win.x0);
          let s = ((y - e.y0) * tw + (ox0 - e.x0)) * 4;
          for (let x = ox0; x < ox1; x++, t++, s += 4) {
            const base = t * R;
            for (let j = 0; j < R; j++) dst[base + j] = src[j][s + ch[j]];
          }
        }
      });
    }
    return out;
  }
}
