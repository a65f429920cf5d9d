//! Marching cubes over a scalar field given by a batched sampler callback, so that a neural SDF is
//! evaluated in large batches and a 512³ grid never has to be held in memory: the grid is swept one
//! z-plane at a time (two planes of values and their edge vertices alive at once), planes are
//! evaluated in blocks that fill one sampler batch, and each grid edge owns a single vertex shared by
//! every cell that uses it, so a closed surface comes out watertight without welding.

pub use crate::mc_band::NarrowBand;
use crate::mc_band::{BandMask, SubBand};
use crate::mc_tables::{case_table, CaseLoop};
use crate::memory::{gib, MachineMemory};
use i2sdf_data::mesh::TriangleMesh;
use i2sdf_data::DataError;
use rayon::prelude::*;

/// A regular grid of samples over an axis-aligned box (`samples` points per axis, corners included).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct McGrid {
    pub min: [f32; 3],
    pub max: [f32; 3],
    pub samples: [usize; 3],
}

impl McGrid {
    /// Cubic cells: `resolution` samples along the box's longest axis, the same spacing on the
    /// others (the box's max corner grows by less than one cell to fit a whole number of cells).
    pub fn cubic(min: [f32; 3], max: [f32; 3], resolution: usize) -> Result<McGrid, DataError> {
        if resolution < 2 {
            return Err(DataError::invalid(format!(
                "marching cubes resolution must be at least 2, got {resolution}"
            )));
        }
        let extent: [f64; 3] = std::array::from_fn(|k| max[k] as f64 - min[k] as f64);
        if extent.iter().any(|e| !e.is_finite() || *e <= 0.0) {
            return Err(DataError::invalid(format!(
                "marching cubes box is empty or not finite: min {min:?}, max {max:?}"
            )));
        }
        let step = extent.iter().cloned().fold(0.0, f64::max) / (resolution - 1) as f64;
        let samples: [usize; 3] = std::array::from_fn(|k| ((extent[k] / step - 1e-9).ceil() as usize + 1).max(2));
        let max = std::array::from_fn(|k| (min[k] as f64 + (samples[k] - 1) as f64 * step) as f32);
        Ok(McGrid { min, max, samples })
    }

    /// Bytes an extraction of this grid holds at its peak (`batch_points` per sampler call): two
    /// z-planes of values and of x/y-edge vertex ids, one plane of z-edge ids (4 bytes each), the
    /// sampler's block (at least one plane) and its points, and the mesh. The mesh is estimated
    /// from the box's surface in cells: an indoor scene's walls lie near the box's faces and the
    /// furniture adds about as much again ([`MESH_VERTICES_PER_FACE_CELL`]); each vertex costs
    /// its position and two triangles, twice over for the vectors' growth; and a narrow band's
    /// coarse grid. Saturates (f64).
    pub fn memory_estimate(&self, options: &McOptions) -> f64 {
        let batch_points = options.batch_points;
        let band = options.narrow_band.as_ref().map_or(0.0, |b| {
            BandMask::memory_estimate(self, b) + SubBand::memory_estimate(self, b)
        });
        let [nx, ny, nz] = self.samples.map(|n| n as f64);
        let plane = nx * ny;
        let block = plane.max(batch_points as f64);
        let planes = plane * 4.0 * (2.0 + 2.0 + 2.0 + 1.0) + block * 4.0 + block.min(batch_points as f64) * 12.0;
        let face_cells = 2.0 * (nx * ny + ny * nz + nx * nz);
        let vertices = MESH_VERTICES_PER_FACE_CELL * face_cells;
        planes + vertices * (12.0 + 2.0 * 12.0) * 2.0 + band
    }

    /// Refuses (bad input, before anything is allocated) a grid whose
    /// [`memory_estimate`](Self::memory_estimate) exceeds `available` bytes; `None` (unknown)
    /// accepts.
    pub fn check_fits(&self, options: &McOptions, available: Option<u64>) -> Result<(), DataError> {
        let need = self.memory_estimate(options);
        match available {
            Some(avail) if need > avail as f64 => {
                let [nx, ny, nz] = self.samples;
                let resolution = nx.max(ny).max(nz);
                Err(DataError::invalid(format!(
                    "marching cubes at resolution {resolution} ({nx}×{ny}×{nz} samples) needs about {}, more than the {} of memory available: lower the resolution",
                    gib(need),
                    gib(avail as f64)
                )))
            }
            _ => Ok(()),
        }
    }

    pub fn step(&self) -> [f64; 3] {
        std::array::from_fn(|k| (self.max[k] as f64 - self.min[k] as f64) / (self.samples[k] - 1) as f64)
    }

    pub fn point(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        let step = self.step();
        let idx = [i, j, k];
        std::array::from_fn(|a| self.min[a] as f64 + idx[a] as f64 * step[a])
    }
}

/// Mesh vertices per cell of the grid box's surface (see [`McGrid::memory_estimate`]): measured
/// 1.57 on the default room at 256 (295 502 vertices for 188 608 face cells of its 256×188×104
/// grid), rounded up.
pub const MESH_VERTICES_PER_FACE_CELL: f64 = 2.0;

#[derive(Clone, Debug)]
pub struct McOptions {
    /// The level set to extract (0 for an SDF).
    pub iso: f32,
    /// Points per sampler call (the last call of a block may be smaller).
    pub batch_points: usize,
    /// When set, drop connected components with less than this fraction of the largest one's area
    /// (floaters). Off by default.
    pub min_component_area_fraction: Option<f64>,
    /// When set, evaluate only the fine samples near the level set ([`NarrowBand`]); only for a
    /// field that obeys the band's Lipschitz bound. Off by default: every sample is evaluated.
    pub narrow_band: Option<NarrowBand>,
}

impl McOptions {
    /// The options of [`extract_mesh`](crate::sdf_mesh::extract_mesh) at `resolution`: the defaults and [`NarrowBand::for_sdf`].
    pub fn for_sdf(resolution: usize) -> McOptions {
        McOptions {
            narrow_band: Some(NarrowBand::for_sdf(resolution)),
            ..Default::default()
        }
    }
}

impl Default for McOptions {
    fn default() -> Self {
        McOptions {
            iso: 0.0,
            batch_points: 65536,
            min_component_area_fraction: None,
            narrow_band: None,
        }
    }
}

/// Calls `sampler` and refuses a non-finite value, naming the point.
fn sample_checked<F: FnMut(&[[f32; 3]], &mut [f32])>(
    sampler: &mut F,
    points: &[[f32; 3]],
    out: &mut [f32],
) -> Result<(), DataError> {
    sampler(points, out);
    match out.iter().position(|v| !v.is_finite()) {
        Some(bad) => Err(DataError::invalid(format!(
            "marching cubes: the field is not finite ({}) at {:?}",
            out[bad], points[bad]
        ))),
        None => Ok(()),
    }
}

/// Evaluates whole z-planes of the grid in blocks of about one sampler batch; with a narrow band,
/// only the samples of its active blocks go to the sampler and the others are filled.
struct PlaneSource<'g, F> {
    grid: &'g McGrid,
    sampler: F,
    batch_points: usize,
    band: Option<BandMask>,
    /// The band's second level, when it has one.
    sub: Option<SubBand>,
    block_first_plane: usize,
    block_planes: usize,
    block_values: Vec<f32>,
    points: Vec<[f32; 3]>,
    /// Indices into `block_values` of the batch in `points`.
    targets: Vec<usize>,
    batch_values: Vec<f32>,
}

impl<'g, F: FnMut(&[[f32; 3]], &mut [f32])> PlaneSource<'g, F> {
    /// The planes of `grid` from `sampler`; with a narrow band (step > 1), its mask is built
    /// first, from a coarse pass of the sampler.
    fn new(grid: &'g McGrid, options: &McOptions, mut sampler: F) -> Result<Self, DataError> {
        let band = match &options.narrow_band {
            Some(b) if b.step > 1 => Some(BandMask::build(grid, b, options.iso, options.batch_points, |p, v| {
                sample_checked(&mut sampler, p, v)
            })?),
            _ => None,
        };
        let sub = match (&band, &options.narrow_band) {
            (Some(mask), Some(b)) => SubBand::new(grid, mask, b, options.iso),
            _ => None,
        };
        Ok(PlaneSource {
            grid,
            sampler,
            batch_points: options.batch_points,
            band,
            sub,
            block_first_plane: 0,
            block_planes: 0,
            block_values: Vec::new(),
            points: Vec::new(),
            targets: Vec::new(),
            batch_values: Vec::new(),
        })
    }

    fn plane_len(&self) -> usize {
        self.grid.samples[0] * self.grid.samples[1]
    }

    /// Evaluates the queued points and scatters their values into the block.
    fn flush(&mut self) -> Result<(), DataError> {
        if self.points.is_empty() {
            return Ok(());
        }
        self.batch_values.resize(self.points.len(), 0.0);
        sample_checked(&mut self.sampler, &self.points, &mut self.batch_values)?;
        for (&t, &v) in self.targets.iter().zip(&self.batch_values) {
            self.block_values[t] = v;
        }
        self.points.clear();
        self.targets.clear();
        Ok(())
    }

    /// Copies plane `k`'s values (x fastest) into `out`.
    fn plane(&mut self, k: usize, out: &mut [f32]) -> Result<(), DataError> {
        let plane_len = self.plane_len();
        if k < self.block_first_plane || k >= self.block_first_plane + self.block_planes {
            let planes_per_block = (self.batch_points / plane_len).max(1);
            self.block_first_plane = k;
            self.block_planes = planes_per_block.min(self.grid.samples[2] - k);
            let total = self.block_planes * plane_len;
            self.block_values.resize(total, 0.0);
            if let (Some(mask), Some(sub)) = (&self.band, self.sub.as_mut()) {
                let sampler = &mut self.sampler;
                let last = k + self.block_planes - 1;
                sub.prepare(self.grid, mask, k, last, self.batch_points, |p, v| {
                    sample_checked(sampler, p, v)
                })?;
            }
            let (nx, grid, band, sub) = (self.grid.samples[0], self.grid, self.band.as_ref(), self.sub.as_ref());
            // Row by row in parallel: the band's samples filled, the others' points listed (in
            // order, so the sampler's batches are what a serial sweep makes). Why: done serially,
            // it held the sweep for a sixth of the mesh's CPU time at 1024 on 2 cores.
            // Each task folds its rows into one list (rows in order within it, tasks in order in
            // `listed`) with one band row view, so nothing is allocated per row.
            let listed: Vec<(Vec<usize>, Vec<[f32; 3]>)> = self.block_values[..total]
                .par_chunks_mut(nx)
                .enumerate()
                .with_min_len(64)
                .fold(
                    || (Vec::new(), Vec::new(), band.map(|b| b.row_view(sub))),
                    |(mut targets, mut points, mut band_row), (row, values)| {
                        let flat0 = row * nx;
                        let (kk, j) = (k + flat0 / plane_len, (flat0 % plane_len) / nx);
                        if let Some(r) = band_row.as_mut() {
                            r.move_to(j, kk);
                        }
                        for (i, v) in values.iter_mut().enumerate() {
                            if let Some(value) = band_row.as_ref().and_then(|r| r.value(i)) {
                                *v = value;
                                continue;
                            }
                            let q = grid.point(i, j, kk);
                            points.push([q[0] as f32, q[1] as f32, q[2] as f32]);
                            targets.push(flat0 + i);
                        }
                        (targets, points, band_row)
                    },
                )
                .map(|(targets, points, _)| (targets, points))
                .collect();
            for (targets, points) in listed {
                for (t, q) in targets.into_iter().zip(points) {
                    self.points.push(q);
                    self.targets.push(t);
                    if self.points.len() == self.batch_points {
                        self.flush()?;
                    }
                }
            }
            self.flush()?;
        }
        let offset = (k - self.block_first_plane) * plane_len;
        out.copy_from_slice(&self.block_values[offset..offset + plane_len]);
        Ok(())
    }
}

const NO_VERTEX: u32 = u32::MAX;

/// Extracts the `options.iso` level set of the field as a triangle mesh whose faces point toward
/// the positive side of the field (outward from the surface into free space for an SDF).
/// `sampler(points, values)` must fill `values[i]` with the field at `points[i]`.
pub fn marching_cubes<F>(grid: &McGrid, options: &McOptions, sampler: F) -> Result<TriangleMesh, DataError>
where
    F: FnMut(&[[f32; 3]], &mut [f32]) + Send,
{
    let [nx, ny, nz] = grid.samples;
    if nx < 2 || ny < 2 || nz < 2 {
        return Err(DataError::invalid(format!(
            "marching cubes grid needs at least 2 samples per axis, got {:?}",
            grid.samples
        )));
    }
    if options.batch_points == 0 {
        return Err(DataError::invalid("marching cubes batch size must be positive"));
    }
    // Before anything is allocated: a resolution that cannot fit is refused, not swapped to death.
    grid.check_fits(options, MachineMemory::read().map(|m| m.available))?;
    let mut source = PlaneSource::new(grid, options, sampler)?;
    let mut slab = Slab::new(grid, options.iso);
    let mut ahead = vec![0.0; nx * ny];
    source.plane(0, &mut slab.values[0])?;
    source.plane(1, &mut ahead)?;
    slab.plane_vertices(0, 0);
    for k in 0..nz - 1 {
        let (lo, hi) = (k % 2, (k + 1) % 2);
        std::mem::swap(&mut slab.values[hi], &mut ahead);
        // Plane k + 2 is sampled while planes k and k + 1 are polygonized. Why: the
        // polygonization is serial, and one plane after the other it left a core idle for a
        // tenth of the mesh's time at 1024 (1.55 cores busy on 2).
        let (sampled, ()) = rayon::join(
            || match k + 2 < nz {
                true => source.plane(k + 2, &mut ahead),
                false => Ok(()),
            },
            || {
                slab.plane_vertices(k + 1, hi);
                slab.z_edge_vertices(k, lo, hi);
                slab.cell_faces(lo, hi);
            },
        );
        sampled?;
    }
    let mut mesh = slab.mesh;
    if let Some(fraction) = options.min_component_area_fraction {
        mesh.remove_small_components(fraction);
    }
    Ok(mesh)
}

/// The sweep's two live z-planes (index 0 or 1 by parity): their samples and the samples' signs
/// as bit rows, the vertex ids of their crossing x- and y-edges and of the z-edges between them
/// (with the slots each set, to reset), and the mesh so far.
///
/// Why bit rows: at 1024 the sweep visits 10⁹ samples and cells, of which a few in a thousand
/// touch the surface, and visiting each one by one held the extraction on one core for about half
/// of its wall time (the SDF queries run on every core). A row's crossings are the bits where a
/// sign row differs from its neighbour, 64 samples a word, and only those are visited, in the
/// same order as a sample-by-sample sweep, so the mesh is the same to the byte.
struct Slab<'g> {
    grid: &'g McGrid,
    iso: f32,
    nx: usize,
    ny: usize,
    /// u64 words per bit row.
    words: usize,
    values: [Vec<f32>; 2],
    /// Bit i of row j (word `j * words + i / 64`) set where the sample is below the iso value.
    signs: [Vec<u64>; 2],
    x_edges: [Vec<u32>; 2],
    y_edges: [Vec<u32>; 2],
    z_edges: Vec<u32>,
    /// The slots of `x_edges[p]` / `y_edges[p]` (together) and of `z_edges` holding a vertex.
    set_xy: [Vec<u32>; 2],
    set_z: Vec<u32>,
    mesh: TriangleMesh,
}

/// Bits `i` of `row` where bit `i` and bit `i + 1` differ (bit `i + 1` of the last word read
/// from the next word).
#[inline]
fn neighbour_differs(row: &[u64], w: usize) -> u64 {
    let next = row.get(w + 1).map_or(0, |n| n << 63);
    row[w] ^ ((row[w] >> 1) | next)
}

/// Bits `i` of `row` where bit `i` or bit `i + 1` is set (as [`neighbour_differs`]).
#[inline]
fn with_neighbour(row: &[u64], w: usize) -> u64 {
    let next = row.get(w + 1).map_or(0, |n| n << 63);
    row[w] | (row[w] >> 1) | next
}

impl<'g> Slab<'g> {
    fn new(grid: &'g McGrid, iso: f32) -> Self {
        let [nx, ny, _] = grid.samples;
        let plane_len = nx * ny;
        let words = nx.div_ceil(64);
        Slab {
            grid,
            iso,
            nx,
            ny,
            words,
            values: [vec![0.0f32; plane_len], vec![0.0f32; plane_len]],
            signs: [vec![0u64; words * ny], vec![0u64; words * ny]],
            x_edges: [vec![NO_VERTEX; plane_len], vec![NO_VERTEX; plane_len]],
            y_edges: [vec![NO_VERTEX; plane_len], vec![NO_VERTEX; plane_len]],
            z_edges: vec![NO_VERTEX; plane_len],
            set_xy: [Vec::new(), Vec::new()],
            set_z: Vec::new(),
            mesh: TriangleMesh::default(),
        }
    }

    fn idx(&self, i: usize, j: usize) -> usize {
        i + self.nx * j
    }

    /// Bits of word `w` of a row that stand for samples `< limit` (i = 64 w + bit).
    #[inline]
    fn below(w: usize, limit: usize) -> u64 {
        let first = 64 * w;
        match limit.saturating_sub(first) {
            0 => 0,
            n if n >= 64 => u64::MAX,
            n => (1u64 << n) - 1,
        }
    }

    /// Visits the set bits of `bits` (word `w` of a row) in ascending order as sample indices.
    #[inline]
    fn for_bits(mut bits: u64, w: usize, mut f: impl FnMut(usize)) {
        while bits != 0 {
            f(64 * w + bits.trailing_zeros() as usize);
            bits &= bits - 1;
        }
    }

    /// The sign rows of plane `p` from its samples.
    fn set_signs(&mut self, p: usize) {
        let (nx, words, iso) = (self.nx, self.words, self.iso);
        let (vals, signs) = (&self.values[p], &mut self.signs[p]);
        for (row, bits) in vals.chunks_exact(nx).zip(signs.chunks_exact_mut(words)) {
            for (w, chunk) in row.chunks(64).enumerate() {
                bits[w] = chunk
                    .iter()
                    .enumerate()
                    .fold(0u64, |m, (b, &v)| m | (((v < iso) as u64) << b));
            }
        }
    }

    /// Creates the vertices on the crossing x- and y-edges of plane `k`, held as plane `p` (its
    /// samples in `values[p]`), in sample order, an x-edge before the y-edge of the same sample.
    fn plane_vertices(&mut self, k: usize, p: usize) {
        self.set_signs(p);
        let (grid, iso, nx, ny, words) = (self.grid, self.iso, self.nx, self.ny, self.words);
        for &at in &self.set_xy[p] {
            self.x_edges[p][at as usize] = NO_VERTEX;
            self.y_edges[p][at as usize] = NO_VERTEX;
        }
        self.set_xy[p].clear();
        let (vals, signs) = (&self.values[p], &self.signs[p]);
        let (xe, ye, set) = (&mut self.x_edges[p], &mut self.y_edges[p], &mut self.set_xy[p]);
        let mesh = &mut self.mesh;
        for j in 0..ny {
            let row = &signs[j * words..(j + 1) * words];
            let up = (j + 1 < ny).then(|| &signs[(j + 1) * words..(j + 2) * words]);
            for w in 0..words {
                let xs = neighbour_differs(row, w) & Self::below(w, nx - 1);
                let ys = up.map_or(0, |up| (row[w] ^ up[w]) & Self::below(w, nx));
                Self::for_bits(xs | ys, w, |i| {
                    let at = i + nx * j;
                    let v = vals[at];
                    if xs >> (i % 64) & 1 != 0 {
                        xe[at] = add_vertex(mesh, iso, grid.point(i, j, k), v, grid.point(i + 1, j, k), vals[at + 1]);
                    }
                    if ys >> (i % 64) & 1 != 0 {
                        ye[at] = add_vertex(
                            mesh,
                            iso,
                            grid.point(i, j, k),
                            v,
                            grid.point(i, j + 1, k),
                            vals[at + nx],
                        );
                    }
                    set.push(at as u32);
                });
            }
        }
    }

    /// Creates the vertices on the crossing z-edges between plane `k` (held as `lo`) and `k + 1`
    /// (held as `hi`), in sample order.
    fn z_edge_vertices(&mut self, k: usize, lo: usize, hi: usize) {
        let (grid, iso, nx, words) = (self.grid, self.iso, self.nx, self.words);
        for &at in &self.set_z {
            self.z_edges[at as usize] = NO_VERTEX;
        }
        self.set_z.clear();
        let (zs, set, mesh) = (&mut self.z_edges, &mut self.set_z, &mut self.mesh);
        let (a, b) = (&self.signs[lo], &self.signs[hi]);
        let (va, vb) = (&self.values[lo], &self.values[hi]);
        for j in 0..self.ny {
            for w in 0..words {
                let bits = a[j * words + w] ^ b[j * words + w];
                Self::for_bits(bits, w, |i| {
                    let at = i + nx * j;
                    zs[at] = add_vertex(mesh, iso, grid.point(i, j, k), va[at], grid.point(i, j, k + 1), vb[at]);
                    set.push(at as u32);
                });
            }
        }
    }

    /// Triangulates every cell between the planes held as `lo` (below) and `hi` (above) that
    /// the surface crosses (its corners' signs not all equal), in cell order.
    fn cell_faces(&mut self, lo: usize, hi: usize) {
        let table = case_table();
        let (nx, words) = (self.nx, self.words);
        for j in 0..self.ny - 1 {
            let rows = [
                &self.signs[lo][j * words..(j + 1) * words],
                &self.signs[lo][(j + 1) * words..(j + 2) * words],
                &self.signs[hi][j * words..(j + 1) * words],
                &self.signs[hi][(j + 1) * words..(j + 2) * words],
            ];
            for w in 0..words {
                let (mut any, mut all) = (0u64, u64::MAX);
                for r in rows {
                    any |= with_neighbour(r, w);
                    // A cell's corners all set: bit i and bit i + 1 of each row.
                    let next = r.get(w + 1).map_or(0, |n| n << 63);
                    all &= r[w] & ((r[w] >> 1) | next);
                }
                let crossed = any & !all & Self::below(w, nx - 1);
                let mut bits = crossed;
                while bits != 0 {
                    let i = 64 * w + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let config = self.cell_case(i, j, lo, hi);
                    let edge_vertex = self.cell_edge_vertices(i, j, lo, hi);
                    add_case_faces(&mut self.mesh, &table[config], &edge_vertex);
                }
            }
        }
    }

    /// The case of cell `(i, j)`: bit `c` set when its corner `c` (x: bit 0, y: bit 1, z: bit 2)
    /// is below the iso value.
    fn cell_case(&self, i: usize, j: usize, lo: usize, hi: usize) -> usize {
        let mut config = 0usize;
        for c in 0..8 {
            let plane = if c & 4 != 0 { hi } else { lo };
            let v = self.values[plane][self.idx(i + (c & 1), j + ((c >> 1) & 1))];
            if v < self.iso {
                config |= 1 << c;
            }
        }
        config
    }

    /// Cell edge id → the grid edge's vertex, in the order of EDGE_CORNERS.
    fn cell_edge_vertices(&self, i: usize, j: usize, lo: usize, hi: usize) -> [u32; 12] {
        let idx = |i: usize, j: usize| self.idx(i, j);
        let (xe, ye, ze) = (&self.x_edges, &self.y_edges, &self.z_edges);
        [
            xe[lo][idx(i, j)],
            xe[lo][idx(i, j + 1)],
            xe[hi][idx(i, j)],
            xe[hi][idx(i, j + 1)],
            ye[lo][idx(i, j)],
            ye[lo][idx(i + 1, j)],
            ye[hi][idx(i, j)],
            ye[hi][idx(i + 1, j)],
            ze[idx(i, j)],
            ze[idx(i + 1, j)],
            ze[idx(i, j + 1)],
            ze[idx(i + 1, j + 1)],
        ]
    }
}

/// Adds the `iso` crossing on the edge from `pa` (value `va`) to `pb` (value `vb`) to the mesh;
/// returns its id.
fn add_vertex(mesh: &mut TriangleMesh, iso: f32, pa: [f64; 3], va: f32, pb: [f64; 3], vb: f32) -> u32 {
    let t = (iso as f64 - va as f64) / (vb as f64 - va as f64);
    mesh.positions
        .push(std::array::from_fn(|a| (pa[a] + t * (pb[a] - pa[a])) as f32));
    (mesh.positions.len() - 1) as u32
}

/// The faces of one cell's case (its vertices by cell edge in `edge_vertex`): each loop as a fan,
/// or as a fan around a new centre vertex where it needs one.
fn add_case_faces(mesh: &mut TriangleMesh, case: &[CaseLoop], edge_vertex: &[u32; 12]) {
    for case_loop in case {
        if !case_loop.needs_center {
            for tri in case_loop.fan() {
                mesh.faces.push(tri.map(|e| edge_vertex[e as usize]));
            }
            continue;
        }
        let n = case_loop.edges.len();
        let mut center = [0.0f32; 3];
        for &e in &case_loop.edges {
            let p = mesh.positions[edge_vertex[e as usize] as usize];
            (0..3).for_each(|a| center[a] += p[a] / n as f32);
        }
        mesh.positions.push(center);
        let c = (mesh.positions.len() - 1) as u32;
        for k in 0..n {
            let (a, b) = (case_loop.edges[k], case_loop.edges[(k + 1) % n]);
            mesh.faces.push([c, edge_vertex[a as usize], edge_vertex[b as usize]]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn norm(p: [f32; 3]) -> f64 {
        p.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt()
    }

    fn sphere_sdf(center: [f32; 3], radius: f32) -> impl Fn(&[[f32; 3]], &mut [f32]) + Send + Sync {
        move |points, out| {
            for (p, o) in points.iter().zip(out.iter_mut()) {
                let d = [p[0] - center[0], p[1] - center[1], p[2] - center[2]];
                *o = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - radius;
            }
        }
    }

    #[test]
    fn sphere_area_volume_watertight_and_outward() {
        let r = 0.6f32;
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], 96).unwrap();
        let mut calls = 0;
        let sdf = sphere_sdf([0.0; 3], r);
        let options = McOptions {
            batch_points: 20000,
            ..Default::default()
        };
        let mesh = marching_cubes(&grid, &options, |p, v| {
            calls += 1;
            assert!(p.len() <= 20000);
            sdf(p, v)
        })
        .unwrap();
        assert!(calls > 1, "batched evaluation");
        let (r64, h) = (r as f64, 2.0 / 95.0);
        let area = mesh.surface_area();
        let volume = mesh.signed_volume();
        let (true_area, true_volume) = (4.0 * PI * r64 * r64, 4.0 / 3.0 * PI * r64.powi(3));
        assert!((area / true_area - 1.0).abs() < 0.01, "area {area} vs {true_area}");
        assert!(volume > 0.0, "outward orientation gives positive volume");
        assert!(
            (volume / true_volume - 1.0).abs() < 0.01,
            "volume {volume} vs {true_volume}"
        );
        for &p in &mesh.positions {
            assert!(
                (norm(p) - r64).abs() < 0.02 * h,
                "vertex off the surface: {}",
                norm(p) - r64
            );
        }
        assert!(mesh.is_watertight_and_consistently_oriented());
        // Each face's normal points away from the centre (the positive side).
        for f in 0..mesh.num_faces() {
            let n = mesh.face_area_vector(f);
            let c = mesh.triangle(f);
            let centroid: [f64; 3] = std::array::from_fn(|a| (c[0][a] + c[1][a] + c[2][a]) as f64 / 3.0);
            assert!(i2sdf_data::mesh::dot(n, centroid) > 0.0);
        }
    }

    #[test]
    fn inverted_sphere_points_inward() {
        // An indoor-style SDF (positive inside the room): normals face the free space inside.
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], 40).unwrap();
        let sdf = sphere_sdf([0.0; 3], 0.7);
        let mesh = marching_cubes(&grid, &McOptions::default(), |p, v| {
            sdf(p, v);
            v.iter_mut().for_each(|x| *x = -*x);
        })
        .unwrap();
        assert!(mesh.signed_volume() < 0.0);
        assert!(mesh.is_watertight_and_consistently_oriented());
    }

    #[test]
    fn noisy_field_is_still_watertight() {
        // A bumpy closed surface with many ambiguous faces: watertightness comes from the face rule.
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], 33).unwrap();
        let field = |p: &[[f32; 3]], v: &mut [f32]| {
            for (p, o) in p.iter().zip(v.iter_mut()) {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let bumps = 0.15 * (17.0 * p[0]).sin() * (19.0 * p[1]).sin() * (23.0 * p[2]).sin();
                *o = r - 0.6 + bumps;
            }
        };
        let mesh = marching_cubes(&grid, &McOptions::default(), field).unwrap();
        assert!(mesh.num_faces() > 1000);
        assert!(mesh.is_watertight_and_consistently_oriented());
        assert!(mesh.signed_volume() > 0.0);
    }

    #[test]
    fn random_field_closed_by_positive_border_is_watertight() {
        // White noise hits every ambiguous configuration; the positive border closes the surface.
        use rand::{Rng, SeedableRng};
        let grid = McGrid::cubic([0.0; 3], [1.0; 3], 24).unwrap();
        let n = grid.samples[0];
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let noise: Vec<f32> = (0..n * n * n).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let field = |p: &[[f32; 3]], v: &mut [f32]| {
            for (p, o) in p.iter().zip(v.iter_mut()) {
                let ijk = p.map(|x| (x * (n - 1) as f32).round() as usize);
                let border = ijk.iter().any(|&i| i == 0 || i == n - 1);
                *o = if border {
                    1.0
                } else {
                    noise[ijk[0] + n * (ijk[1] + n * ijk[2])]
                };
            }
        };
        let mesh = marching_cubes(&grid, &McOptions::default(), field).unwrap();
        assert!(mesh.num_faces() > 10000);
        assert!(mesh.is_watertight_and_consistently_oriented());
    }

    #[test]
    fn rows_across_word_boundaries_get_every_crossing_once() {
        // 130 samples a row: two full 64-bit words and a partial one, so the sweep's bit rows
        // carry neighbours across words and mask the last word's padding. White noise: every
        // sign-changing grid edge must get exactly one vertex (plus the case table's centre
        // vertices), and the mesh must close.
        use rand::{Rng, SeedableRng};
        let grid = McGrid {
            min: [0.0; 3],
            max: [1.0; 3],
            samples: [130, 7, 6],
        };
        let [nx, ny, nz] = grid.samples;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let noise: Vec<f32> = (0..nx * ny * nz).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let at = |i: usize, j: usize, k: usize| i + nx * (j + ny * k);
        let border =
            |i: usize, j: usize, k: usize| i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1;
        let value = |i: usize, j: usize, k: usize| if border(i, j, k) { 1.0 } else { noise[at(i, j, k)] };
        let step = grid.step();
        let field = |p: &[[f32; 3]], v: &mut [f32]| {
            for (p, o) in p.iter().zip(v.iter_mut()) {
                let ijk: [usize; 3] =
                    std::array::from_fn(|a| ((p[a] as f64 - grid.min[a] as f64) / step[a]).round() as usize);
                *o = value(ijk[0], ijk[1], ijk[2]);
            }
        };
        let mesh = marching_cubes(&grid, &McOptions::default(), field).unwrap();
        // Each sign-changing grid edge's vertex, placed as the sweep places it, must be in the
        // mesh exactly once.
        let mut count = std::collections::HashMap::new();
        for p in &mesh.positions {
            *count.entry(p.map(f32::to_bits)).or_insert(0) += 1;
        }
        let mut crossings = 0;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let v = value(i, j, k);
                    for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        let (a, b, c) = (i + di, j + dj, k + dk);
                        if a >= nx || b >= ny || c >= nz || (value(a, b, c) < 0.0) == (v < 0.0) {
                            continue;
                        }
                        crossings += 1;
                        let w = value(a, b, c);
                        let (pa, pb) = (grid.point(i, j, k), grid.point(a, b, c));
                        let t = -(v as f64) / (w as f64 - v as f64);
                        let q: [f32; 3] = std::array::from_fn(|x| (pa[x] + t * (pb[x] - pa[x])) as f32);
                        assert_eq!(
                            count.get(&q.map(f32::to_bits)),
                            Some(&1),
                            "edge ({i}, {j}, {k}) + ({di}, {dj}, {dk})"
                        );
                    }
                }
            }
        }
        assert!(crossings > 1000);
        assert!(mesh.is_watertight_and_consistently_oriented());
    }

    #[test]
    fn blocks_and_batches_do_not_change_the_mesh() {
        let grid = McGrid::cubic([-1.0, -0.5, -1.0], [1.0, 0.5, 1.0], 30).unwrap();
        let sdf = sphere_sdf([0.1, 0.0, -0.1], 0.45);
        let a = marching_cubes(
            &grid,
            &McOptions {
                batch_points: 7,
                ..Default::default()
            },
            &sdf,
        )
        .unwrap();
        let b = marching_cubes(
            &grid,
            &McOptions {
                batch_points: 1 << 20,
                ..Default::default()
            },
            &sdf,
        )
        .unwrap();
        assert_eq!(a, b);
        assert_eq!(grid.samples[1], 16);
    }

    #[test]
    fn floaters_removed_on_request() {
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], 48).unwrap();
        let two_spheres = |p: &[[f32; 3]], v: &mut [f32]| {
            let big = sphere_sdf([-0.3, 0.0, 0.0], 0.5);
            let small = sphere_sdf([0.7, 0.0, 0.0], 0.12);
            let mut w = vec![0.0; v.len()];
            big(p, v);
            small(p, &mut w);
            v.iter_mut().zip(&w).for_each(|(a, b)| *a = a.min(*b));
        };
        let all = marching_cubes(&grid, &McOptions::default(), two_spheres).unwrap();
        assert_eq!(all.face_components().1, 2);
        let options = McOptions {
            min_component_area_fraction: Some(0.2),
            ..Default::default()
        };
        let kept = marching_cubes(&grid, &options, two_spheres).unwrap();
        assert_eq!(kept.face_components().1, 1);
        assert!(kept.positions.iter().all(|p| p[0] < 0.3));
        assert!(kept.is_watertight_and_consistently_oriented());
    }

    #[test]
    fn a_grid_that_does_not_fit_is_refused_before_sampling() {
        let batch = McOptions::default();
        let huge = McGrid::cubic([-1.0; 3], [1.0; 3], 100_000).unwrap();
        // 10^10 samples per plane at 32 bytes each and a mesh of ~10^11 vertices: ~9 TB, far
        // beyond 1 GiB (and any machine's memory).
        assert!(huge.memory_estimate(&batch) > 1e12);
        let err = huge.check_fits(&batch, Some(1 << 30)).unwrap_err();
        let msg = err.to_string();
        assert!(err.is_bad_input());
        for needle in ["resolution 100000", "100000×100000×100000", "1.00 GiB", "available"] {
            assert!(msg.contains(needle), "{needle}: {msg}");
        }
        let mut calls = 0;
        let e = marching_cubes(&huge, &McOptions::default(), |_, v| {
            calls += 1;
            v.fill(1.0)
        });
        assert!(e.is_err() && calls == 0, "refused before the field is sampled");
        // A small grid fits, and an unknown machine accepts.
        let small = McGrid::cubic([-1.0; 3], [1.0; 3], 64).unwrap();
        assert!(small.memory_estimate(&batch) < 64e6);
        assert!(small.check_fits(&batch, Some(1 << 30)).is_ok());
        assert!(huge.check_fits(&batch, None).is_ok());
    }

    #[test]
    fn non_finite_field_is_an_error() {
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], 4).unwrap();
        let err = marching_cubes(&grid, &McOptions::default(), |_, v| v.fill(f32::NAN)).unwrap_err();
        assert!(err.to_string().contains("not finite"));
        assert!(McGrid::cubic([0.0; 3], [1.0; 3], 1).is_err());
    }
}
