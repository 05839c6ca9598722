//! The decoder MLP of the neural model: `(latent, direction encoding) -> hidden -> hidden -> RGB`,
//! two hidden layers of one width, ELU or ReLU. Its parameters live in one flat vector (what Adam
//! updates and the file stores, layer by layer), each weight matrix row-major `[out][in]`, the
//! latent inputs first (NeuralRTI's order: latents, then the light's x and y).
//!
//! The direction encoding is the (x, y) of the directions ([`Directions`]) followed by learned
//! features: per direction (view, light, half vector) a `grid x grid` table of `features`
//! channels over the elevated concentric square (paper 004, section 6.1; `btfrs_hemimap`),
//! looked up bilinearly. A small MLP fed raw coordinates cannot draw the sharp shadow and
//! highlight boundaries of a BTF's directions (measured: worse than a linear PCA of as many
//! components); the tables give it a learned basis over each hemisphere, continuous in the
//! directions, for a few thousand floats.
//!
//! With a horizon map ([`Shape::horizon`] azimuth bins per texel, `crate::relief`), the decoder
//! also reads each direction's **clearance** above the texel's horizon, `elevation(d) -
//! horizon(azimuth(d))` (the light's; the view's too for a BTF): the relief around the texel
//! says where a cast shadow's edge falls between the measured lights, which the texel's own
//! values cannot. The clearances are per (texel, direction) inputs, after the coordinates.

use btfrs_core::{Error, Result};

/// How the (view, light) pair is fed to the decoder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Directions {
    /// The light's (x, y) only: NeuralRTI's form, for captures with one view.
    Light,
    /// The (x, y) of the view and of the light.
    Xy,
    /// The (x, y) of the view and of the light, and the (x, y) of their half vector.
    Half,
}

impl Directions {
    /// Inputs it adds to the latents.
    pub fn dims(self) -> usize {
        match self {
            Directions::Light => 2,
            Directions::Xy => 4,
            Directions::Half => 6,
        }
    }
    /// Its code in files and on the GPU.
    pub fn code(self) -> i32 {
        self as i32
    }
    /// The encoding of code `c`.
    pub fn from_code(c: i32) -> Option<Directions> {
        [Directions::Light, Directions::Xy, Directions::Half].into_iter().find(|d| d.code() == c)
    }
    /// How many directions it looks up in feature tables: the light; view and light; view,
    /// light and half vector.
    pub fn tables(self) -> usize {
        match self {
            Directions::Light => 1,
            Directions::Xy => 2,
            Directions::Half => 3,
        }
    }
    /// Its option name.
    pub fn name(self) -> &'static str {
        match self {
            Directions::Light => "light",
            Directions::Xy => "xy",
            Directions::Half => "half",
        }
    }
    /// The factor the decoder's output is multiplied by: the light's cosine (`l.z`) for the
    /// BTF encodings, whose values include it (a smooth reflectance is then left to the MLP and
    /// grazing lights darken by construction); 1 for NeuralRTI's form, kept exact.
    pub fn gain(self, l: [f64; 3]) -> f32 {
        match self {
            Directions::Light => 1.0,
            Directions::Xy | Directions::Half => l[2].max(0.0) as f32,
        }
    }
    /// The inputs for unit directions `v` and `l` (z >= 0).
    pub fn encode(self, v: [f64; 3], l: [f64; 3], out: &mut [f32]) {
        match self {
            Directions::Light => {
                out[0] = l[0] as f32;
                out[1] = l[1] as f32;
            }
            Directions::Xy | Directions::Half => {
                out[..4].copy_from_slice(&[v[0] as f32, v[1] as f32, l[0] as f32, l[1] as f32]);
                if self == Directions::Half {
                    let h = [v[0] + l[0], v[1] + l[1], v[2] + l[2]];
                    let n = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
                    // Opposite grazing directions have no half vector: take the normal's.
                    let (hx, hy) = if n > 1e-9 { (h[0] / n, h[1] / n) } else { (0.0, 0.0) };
                    out[4] = hx as f32;
                    out[5] = hy as f32;
                }
            }
        }
    }
}

/// The hidden layers' activation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// `x` above 0, `exp(x) - 1` below (NeuralRTI's).
    Elu,
    /// `max(x, 0)`.
    Relu,
}

impl Activation {
    /// Its code in files and on the GPU.
    pub fn code(self) -> i32 {
        self as i32
    }
    /// The activation of code `c`.
    pub fn from_code(c: i32) -> Option<Activation> {
        [Activation::Elu, Activation::Relu].into_iter().find(|a| a.code() == c)
    }
    /// Its option name.
    pub fn name(self) -> &'static str {
        match self {
            Activation::Elu => "elu",
            Activation::Relu => "relu",
        }
    }
    /// Applied in place.
    #[inline]
    pub fn apply(self, x: &mut [f32]) {
        match self {
            Activation::Elu => x.iter_mut().for_each(|v| *v = if *v > 0.0 { *v } else { v.exp_m1() }),
            Activation::Relu => x.iter_mut().for_each(|v| *v = v.max(0.0)),
        }
    }
    /// Applied in place with [`exp_fast`] for ELU: training's form, which vectorizes (a call of
    /// `expm1` per value was a quarter of a training step); evaluation keeps [`Activation::apply`].
    #[inline]
    pub fn apply_fast(self, x: &mut [f32]) {
        match self {
            Activation::Elu => x.iter_mut().for_each(|v| {
                let e = exp_fast(v.min(0.0)) - 1.0;
                *v = if *v > 0.0 { *v } else { e };
            }),
            Activation::Relu => x.iter_mut().for_each(|v| *v = v.max(0.0)),
        }
    }
    /// `d act / d x` times `g`, in place in `g`, from the activation's output `y`.
    #[inline]
    pub fn backward(self, y: &[f32], g: &mut [f32]) {
        match self {
            Activation::Elu => g.iter_mut().zip(y).for_each(|(g, &y)| *g *= if y > 0.0 { 1.0 } else { y + 1.0 }),
            Activation::Relu => g.iter_mut().zip(y).for_each(|(g, &y)| *g *= if y > 0.0 { 1.0 } else { 0.0 }),
        }
    }
}

/// `exp(x)` to a relative error below 3e-7, branch-free so that loops over it vectorize:
/// `2^k exp(r)` with `k` the nearest integer to `x / ln 2`, rounded by the float's own rounding
/// at `1.5 2^23` (whose low mantissa bits then hold `k`: `2^k` is made from them with integer
/// operations, not a float-to-integer conversion, which does not vectorize), `r = x - k ln 2` in
/// `[-ln 2 / 2, ln 2 / 2]` (Cody and Waite's two-part `ln 2`), `exp(r)` by its Taylor polynomial
/// of degree 6 (remainder `r^7 / 7! < 2e-7`).
#[inline(always)]
pub fn exp_fast(x: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let m = x * std::f32::consts::LOG2_E + MAGIC;
    let kf = m - MAGIC;
    let r = x - kf * 0.693_359_4 + kf * 2.121_944_4e-4;
    let p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    let k = m.to_bits().wrapping_sub(MAGIC.to_bits());
    p * f32::from_bits(k.wrapping_add(127) << 23)
}

/// The decoder's shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// Latent channels per texel.
    pub latents: usize,
    /// The direction encoding.
    pub directions: Directions,
    /// Channels of each learned direction table (0: none, NeuralRTI's form).
    pub features: usize,
    /// Nodes per side of each table.
    pub grid: usize,
    /// Width of both hidden layers.
    pub hidden: usize,
    /// The activation of both hidden layers.
    pub activation: Activation,
    /// Azimuth bins of the texels' horizon maps (0: none, no clearance inputs).
    pub horizon: usize,
}

/// Offsets of each layer's parameters in the flat vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Offsets {
    /// `w1 [hidden][latents + directions]`.
    pub w1: usize,
    /// `b1 [hidden]`.
    pub b1: usize,
    /// `w2 [hidden][hidden]`.
    pub w2: usize,
    /// `b2 [hidden]`.
    pub b2: usize,
    /// `w3 [3][hidden]`.
    pub w3: usize,
    /// `b3 [3]`.
    pub b3: usize,
    /// The direction tables, `[table][grid * grid][features]` (view, light, half; as many as
    /// the encoding has).
    pub tables: usize,
    /// Total parameters.
    pub len: usize,
}

impl Shape {
    /// Learned direction tables (0 without features).
    pub fn tables(&self) -> usize {
        if self.features == 0 {
            0
        } else {
            self.directions.tables()
        }
    }
    /// Clearance inputs: the light's above the horizon, and the view's for a BTF encoding (0
    /// without a horizon map).
    pub fn clearances(&self) -> usize {
        match (self.horizon, self.directions) {
            (0, _) => 0,
            (_, Directions::Light) => 1,
            _ => 2,
        }
    }
    /// Inputs besides the latents: coordinates, clearances, then table features.
    pub fn encoding(&self) -> usize {
        self.directions.dims() + self.clearances() + self.tables() * self.features
    }
    /// The directions whose clearances are inputs, in input order.
    pub fn clearance_directions(&self, v: [f64; 3], l: [f64; 3]) -> [[f64; 3]; 2] {
        match self.directions {
            Directions::Light => [l, l],
            _ => [v, l],
        }
    }
    /// Inputs of the first layer.
    pub fn inputs(&self) -> usize {
        self.latents + self.encoding()
    }
    /// Where each layer's parameters are.
    pub fn offsets(&self) -> Offsets {
        let (n, h) = (self.inputs(), self.hidden);
        let w1 = 0;
        let b1 = w1 + h * n;
        let w2 = b1 + h;
        let b2 = w2 + h * h;
        let w3 = b2 + h;
        let b3 = w3 + 3 * h;
        let tables = b3 + 3;
        Offsets { w1, b1, w2, b2, w3, b3, tables, len: tables + self.tables() * self.grid * self.grid * self.features }
    }
}

/// A decoder: its shape and parameters. The parameters are half-precision values (the output
/// layer's times a power of two, [`output_scale`]): [`Decoder::new`] rounds them, so the decoder
/// evaluated on the CPU is the one the renderer reads as halves.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoder {
    /// The shape.
    pub shape: Shape,
    /// Every parameter, laid out as [`Shape::offsets`] says.
    pub params: Vec<f32>,
}

/// The most inputs besides the latents: 6 coordinates, 2 clearances and 3 tables of at most 16
/// features.
pub const MAX_ENCODING: usize = 6 + 2 + 3 * 16;

/// Halves as words, two to a word, the first in the low half (an even count).
fn pack_halves(v: &[u16]) -> Vec<u32> {
    v.chunks(2).map(|w| w[0] as u32 | (w.get(1).copied().unwrap_or(0) as u32) << 16).collect()
}

/// The power of two that brings the output layer (`w3`, `b3`: the data's scale) into half
/// precision's range, its largest value to `[2^14, 2^15)`; 1 for an all-zero layer. The other
/// layers work on unit-scale inputs and are halves as they are.
pub fn output_scale(params: &[f32], o: &Offsets) -> f32 {
    let m = params[o.w3..o.tables].iter().fold(0.0f32, |m, x| m.max(x.abs()));
    if m == 0.0 || !m.is_finite() {
        return 1.0;
    }
    let e = (m.log2().floor() as i32 - 14).clamp(-120, 100);
    2f32.powi(e)
}

/// Bilinear taps of one direction in a table: `(node, weight)` for the four nodes around its
/// point of the concentric square.
pub type Taps = [(u32, f32); 4];

/// The taps of direction `d` in a `grid x grid` table (node `(i, j)` at square point
/// `(i, j) / (grid - 1)`, node index `j * grid + i`).
pub fn taps(d: [f64; 3], grid: usize) -> Taps {
    let [s, t] = btfrs_hemimap::hemisphere_to_square(d);
    let m = (grid - 1) as f64;
    let (x, y) = ((s * m).clamp(0.0, m), (t * m).clamp(0.0, m));
    let (i, j) = ((x.floor() as usize).min(grid - 2), (y.floor() as usize).min(grid - 2));
    let (fx, fy) = ((x - i as f64) as f32, (y - j as f64) as f32);
    let n = (j * grid + i) as u32;
    let g = grid as u32;
    [(n, (1.0 - fx) * (1.0 - fy)), (n + 1, fx * (1.0 - fy)), (n + g, (1.0 - fx) * fy), (n + g + 1, fx * fy)]
}

/// The half vector of unit `v` and `l` (the normal for opposite grazing directions).
pub fn half(v: [f64; 3], l: [f64; 3]) -> [f64; 3] {
    let h = [v[0] + l[0], v[1] + l[1], v[2] + l[2]];
    let n = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
    if n > 1e-9 {
        h.map(|x| x / n)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The taps of each table's direction: the light; view and light; view, light and half.
pub fn table_taps(shape: &Shape, v: [f64; 3], l: [f64; 3]) -> [Taps; 3] {
    let g = shape.grid.max(2);
    match shape.directions {
        Directions::Light => [taps(l, g), taps(l, g), taps(l, g)],
        Directions::Xy => [taps(v, g), taps(l, g), taps(l, g)],
        Directions::Half => [taps(v, g), taps(l, g), taps(half(v, l), g)],
    }
}

/// The pair's part of the encoding from the taps, into `out`: the coordinates, zeros where the
/// clearances go (they are the texel's: [`Decoder::eval`] and the model add them), the table
/// features.
pub fn encode_with(shape: &Shape, params: &[f32], v: [f64; 3], l: [f64; 3], tp: &[Taps; 3], out: &mut [f32]) {
    let d = shape.directions.dims();
    shape.directions.encode(v, l, &mut out[..d]);
    let e = d + shape.clearances();
    out[d..e].fill(0.0);
    let c = shape.features;
    let base = shape.offsets().tables;
    let nodes = shape.grid * shape.grid;
    for (ti, taps) in tp.iter().enumerate().take(shape.tables()) {
        let o = &mut out[e + ti * c..e + (ti + 1) * c];
        o.fill(0.0);
        for &(node, w) in taps {
            let row = &params[base + (ti * nodes + node as usize) * c..][..c];
            o.iter_mut().zip(row).for_each(|(x, f)| *x += w * f);
        }
    }
}

/// The per-query part of the first layer: `b1 + W1[:, latents..] e(v, l)` (the clearances'
/// columns excluded: they are per texel).
pub fn query_bias(shape: &Shape, params: &[f32], v: [f64; 3], l: [f64; 3], out: &mut [f32]) {
    let o = shape.offsets();
    let (n, k, h) = (shape.inputs(), shape.latents, shape.hidden);
    let mut e = [0.0f32; MAX_ENCODING];
    encode_with(shape, params, v, l, &table_taps(shape, v, l), &mut e);
    for j in 0..h {
        let row = &params[o.w1 + j * n + k..o.w1 + (j + 1) * n];
        out[j] = params[o.b1 + j] + row.iter().zip(&e).map(|(w, x)| w * x).sum::<f32>();
    }
}

impl Decoder {
    /// Check the parameters against the shape: the right count, every value finite.
    pub fn new(shape: Shape, params: Vec<f32>, name: &str) -> Result<Decoder> {
        let len = shape.offsets().len;
        if params.len() != len {
            return Err(Error::format(
                name,
                format!(
                    "expected {len} decoder parameters for {} latents, {} directions, {} features on a {} grid \
                     and {} hidden units, got {}",
                    shape.latents,
                    shape.directions.name(),
                    shape.features,
                    shape.grid,
                    shape.hidden,
                    params.len()
                ),
            ));
        }
        if let Some(i) = params.iter().position(|x| !x.is_finite()) {
            return Err(Error::format(name, format!("decoder parameter {i} ({}) is not finite", params[i])));
        }
        let mut params = params;
        let o = shape.offsets();
        let scale = output_scale(&params, &o);
        for (i, x) in params.iter_mut().enumerate() {
            let s = if (o.w3..o.tables).contains(&i) { scale } else { 1.0 };
            let r = half::f16::from_f32(*x / s);
            if r.is_infinite() {
                return Err(Error::format(
                    name,
                    format!("decoder parameter {i} ({x}) is beyond half precision's range (65504)"),
                ));
            }
            *x = r.to_f32() * s;
        }
        Ok(Decoder { shape, params })
    }

    /// The power of two the output layer's halves are scaled by ([`output_scale`]).
    pub fn output_scale(&self) -> f32 {
        output_scale(&self.params, &self.shape.offsets())
    }

    /// The renderer's form of the dense layers: halves packed two to a word, every row padded to
    /// whole vectors of eight (`[w1 rows][n8]`, `b1 [h8]`, `[w2 rows][h8]`, `b2 [h8]`,
    /// `[w3 rows][h8]`, `b3 [1]` in vectors of four words), the output layer divided by
    /// [`Decoder::output_scale`].
    pub fn gpu_dense(&self) -> Vec<u32> {
        let sh = &self.shape;
        let (o, n, h) = (sh.offsets(), sh.inputs(), sh.hidden);
        let inv = 1.0 / self.output_scale();
        let p = &self.params;
        let mut c: Vec<u16> = Vec::new();
        let mut rows = |rows: usize, len: usize, at: usize, s: f32| {
            for r in 0..rows {
                let row = &p[at + r * len..at + (r + 1) * len];
                c.extend(row.iter().map(|&x| half::f16::from_f32(x * s).to_bits()));
                c.resize(c.len().next_multiple_of(8), 0);
            }
        };
        rows(h, n, o.w1, 1.0);
        rows(1, h, o.b1, 1.0);
        rows(h, h, o.w2, 1.0);
        rows(1, h, o.b2, 1.0);
        rows(3, h, o.w3, inv);
        rows(1, 3, o.b3, inv);
        pack_halves(&c)
    }

    /// The renderer's form of the direction tables: halves packed two to a word, each node's
    /// features padded to an even count.
    pub fn gpu_tables(&self) -> Vec<u32> {
        let sh = &self.shape;
        let f = sh.features;
        let nodes = sh.tables() * sh.grid * sh.grid;
        let mut t: Vec<u16> = Vec::with_capacity(nodes * f.next_multiple_of(2));
        for node in self.params[sh.offsets().tables..].chunks(f.max(1)).take(nodes) {
            t.extend(node.iter().map(|&x| half::f16::from_f32(x).to_bits()));
            t.resize(t.len().next_multiple_of(2), 0);
        }
        pack_halves(&t)
    }

    /// The decoder as a reader applies it, on the data's scale: `layer{1,2,3}_weight`
    /// (`[out][in]`, layer 1's inputs the latents, then [`Shape::encoding`]'s coordinates,
    /// clearances and table features), `layer{1,2,3}_bias`, and `tables` (`[tables][grid][grid][features]`,
    /// node `(i, j)` at concentric-square point `(i, j) / (grid - 1)`, indexed `[j][i]`).
    pub fn unpacked(&self) -> btfrs_core::NamedArrays {
        let sh = &self.shape;
        let (o, n, h) = (sh.offsets(), sh.inputs(), sh.hidden);
        let p = &self.params;
        let mut a = btfrs_core::NamedArrays::new();
        for (i, (w, b, rows, cols)) in
            [(o.w1, o.b1, h, n), (o.w2, o.b2, h, h), (o.w3, o.b3, 3, h)].into_iter().enumerate()
        {
            a.put(&format!("layer{}_weight", i + 1), &[rows, cols], p[w..w + rows * cols].to_vec());
            a.put(&format!("layer{}_bias", i + 1), &[rows], p[b..b + rows].to_vec());
        }
        a.put("tables", &[sh.tables(), sh.grid, sh.grid, sh.features], p[o.tables..o.len].to_vec());
        a
    }

    /// `W1[:, ..latents] z`: the per-texel part of the first layer.
    pub fn latent_part(&self, z: &[f32], out: &mut [f32]) {
        let (n, h) = (self.shape.inputs(), self.shape.hidden);
        let w1 = &self.params[self.shape.offsets().w1..];
        for j in 0..h {
            out[j] = w1[j * n..j * n + z.len()].iter().zip(z).map(|(w, x)| w * x).sum();
        }
    }

    /// The RGB output given the first layer's pre-activation `pre1` (latent part plus query
    /// bias); `w2t` is `W2` transposed (`[in][out]`, so the second layer is a sum of rows).
    #[inline]
    pub fn finish(&self, pre1: &mut [f32], w2t: &[f32], scratch: &mut [f32]) -> [f32; 3] {
        let o = self.shape.offsets();
        let h = self.shape.hidden;
        let act = self.shape.activation;
        act.apply(pre1);
        let h2 = &mut scratch[..h];
        h2.copy_from_slice(&self.params[o.b2..o.b2 + h]);
        for (i, &x) in pre1.iter().enumerate() {
            for (a, &w) in h2.iter_mut().zip(&w2t[i * h..(i + 1) * h]) {
                *a += w * x;
            }
        }
        act.apply(h2);
        let mut out = [0.0f32; 3];
        for (c, o3) in out.iter_mut().enumerate() {
            let row = &self.params[o.w3 + c * h..o.w3 + (c + 1) * h];
            *o3 = self.params[o.b3 + c] + row.iter().zip(h2.iter()).map(|(w, x)| w * x).sum::<f32>();
        }
        out
    }

    /// `W2` transposed.
    pub fn w2t(&self) -> Vec<f32> {
        let h = self.shape.hidden;
        let w2 = &self.params[self.shape.offsets().w2..];
        let mut t = vec![0.0f32; h * h];
        for j in 0..h {
            for i in 0..h {
                t[i * h + j] = w2[j * h + i];
            }
        }
        t
    }

    /// The first layer's columns of the clearance inputs, `[clearance][hidden]`.
    pub fn clearance_columns(&self) -> Vec<f32> {
        let sh = &self.shape;
        let (n, h) = (sh.inputs(), sh.hidden);
        let first = sh.latents + sh.directions.dims();
        let w1 = &self.params[sh.offsets().w1..];
        (0..sh.clearances()).flat_map(|i| (0..h).map(move |j| w1[j * n + first + i])).collect()
    }

    /// The output for latent `z` and horizon row `horizon` (its `shape.horizon` angles; empty
    /// without) at directions `v`, `l`, gain included (no cached parts: the reference form).
    pub fn eval(&self, z: &[f32], horizon: &[f32], v: [f64; 3], l: [f64; 3]) -> [f32; 3] {
        let h = self.shape.hidden;
        let mut pre = vec![0.0f32; h];
        let mut q = vec![0.0f32; h];
        self.latent_part(z, &mut pre);
        query_bias(&self.shape, &self.params, v, l, &mut q);
        pre.iter_mut().zip(&q).for_each(|(a, b)| *a += b);
        let cols = self.clearance_columns();
        let dirs = self.shape.clearance_directions(v, l);
        for (i, col) in cols.chunks(h.max(1)).enumerate() {
            let s = crate::relief::clearance(horizon, dirs[i]);
            pre.iter_mut().zip(col).for_each(|(a, w)| *a += w * s);
        }
        let mut scratch = vec![0.0f32; h];
        let g = self.shape.directions.gain(l);
        self.finish(&mut pre, &self.w2t(), &mut scratch).map(|x| x * g)
    }
}
