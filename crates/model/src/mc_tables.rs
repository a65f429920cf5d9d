//! Marching-cubes case tables, generated rather than transcribed.
//!
//! For each of the 256 inside/outside corner configurations, the isosurface's boundary on the cube's
//! surface is built face by face (a face has 0, 2 or 4 crossing edges); segments are directed so that
//! the positive (outside) corners lie on their left seen from outside the cube; the directed segments
//! chain into closed loops that are fan-triangulated. A face with 4 crossings (diagonal corners of
//! equal sign) is resolved by one fixed rule, "cut off each inside corner", which depends only on
//! the face's own corners: the two cells sharing a face resolve it the same way, so the mesh has no
//! cracks (the classic Lorensen–Cline table lacks this guarantee). Loop direction makes every
//! triangle's normal point toward the positive side of the field.

use std::sync::OnceLock;

/// Corner `c` of a unit cell sits at `(c & 1, (c >> 1) & 1, (c >> 2) & 1)`.
pub const fn corner_offset(c: usize) -> [usize; 3] {
    [c & 1, (c >> 1) & 1, (c >> 2) & 1]
}

/// The 12 cell edges as corner pairs: 0–3 along x, 4–7 along y, 8–11 along z.
pub const EDGE_CORNERS: [[usize; 2]; 12] = [
    [0, 1],
    [2, 3],
    [4, 5],
    [6, 7],
    [0, 2],
    [1, 3],
    [4, 6],
    [5, 7],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];

/// One closed loop of the isosurface inside a cell, as cell edge ids in order (counter-clockwise
/// seen from the positive side).
#[derive(Clone, Debug, Default)]
pub struct CaseLoop {
    pub edges: Vec<u8>,
    /// The loop crosses one ambiguous face twice, so a fan diagonal could lie on that face and be
    /// created again by the neighbouring cell: triangulate it around a centre vertex instead.
    pub needs_center: bool,
}

impl CaseLoop {
    /// The fan triangulation, valid when `!needs_center`.
    pub fn fan(&self) -> impl Iterator<Item = [u8; 3]> + '_ {
        (1..self.edges.len() - 1).map(|k| [self.edges[0], self.edges[k], self.edges[k + 1]])
    }
}

pub fn case_table() -> &'static [Vec<CaseLoop>; 256] {
    static TABLE: OnceLock<Box<[Vec<CaseLoop>; 256]>> = OnceLock::new();
    TABLE.get_or_init(|| Box::new(std::array::from_fn(|config| build_case(config as u8))))
}

/// The two cube faces an edge lies on, as `2 * axis + side`.
fn faces_of_edge(edge: usize) -> [usize; 2] {
    let [a, b] = EDGE_CORNERS[edge];
    let (pa, pb) = (corner_offset(a), corner_offset(b));
    let mut faces = (0..3)
        .filter(|&axis| pa[axis] == pb[axis])
        .map(|axis| 2 * axis + pa[axis]);
    [faces.next().unwrap(), faces.next().unwrap()]
}

fn edge_between(a: usize, b: usize) -> usize {
    EDGE_CORNERS
        .iter()
        .position(|&[x, y]| (x == a && y == b) || (x == b && y == a))
        .expect("corners of a cube face are adjacent")
}

fn edge_midpoint(edge: usize) -> [f64; 3] {
    let [a, b] = EDGE_CORNERS[edge];
    let (pa, pb) = (corner_offset(a), corner_offset(b));
    std::array::from_fn(|k| 0.5 * (pa[k] + pb[k]) as f64)
}

fn build_case(config: u8) -> Vec<CaseLoop> {
    let inside = |c: usize| config & (1 << c) != 0;
    // next_edge[e] = the edge the directed boundary goes to from edge e.
    let mut next_edge = [usize::MAX; 12];
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in 0..2 {
            let mut normal = [0.0f64; 3];
            normal[axis] = if side == 1 { 1.0 } else { -1.0 };
            // The face's corners in cyclic order.
            let cycle: [usize; 4] =
                [(0, 0), (1, 0), (1, 1), (0, 1)].map(|(du, dv)| (side << axis) | (du << u) | (dv << v));
            let crossing: Vec<usize> = (0..4)
                .filter(|&k| inside(cycle[k]) != inside(cycle[(k + 1) % 4]))
                .collect();
            // Each segment: (edge slot k1, edge slot k2, a reference corner and whether it is inside);
            // slot k is the edge from cycle[k] to cycle[k + 1].
            let mut segments: Vec<(usize, usize, usize)> = Vec::new();
            match crossing.len() {
                0 => {}
                2 => segments.push((crossing[0], crossing[1], cycle[(crossing[0] + 1) % 4])),
                4 => {
                    // Ambiguous face: cut off each inside corner (slots k-1 and k meet at cycle[k]).
                    for k in 0..4 {
                        if inside(cycle[k]) {
                            segments.push(((k + 3) % 4, k, cycle[k]));
                        }
                    }
                }
                _ => {
                    unreachable!("a closed cycle of 4 corners changes sign an even number of times")
                }
            }
            for (k1, k2, reference) in segments {
                let e1 = edge_between(cycle[k1], cycle[(k1 + 1) % 4]);
                let e2 = edge_between(cycle[k2], cycle[(k2 + 1) % 4]);
                let (p, q) = (edge_midpoint(e1), edge_midpoint(e2));
                let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                let left = [
                    normal[1] * d[2] - normal[2] * d[1],
                    normal[2] * d[0] - normal[0] * d[2],
                    normal[0] * d[1] - normal[1] * d[0],
                ];
                let r = corner_offset(reference);
                let side_of_reference: f64 = (0..3).map(|k| left[k] * (r[k] as f64 - p[k])).sum();
                // Positive corners on the left of the direction, inside corners on the right.
                let forward = (side_of_reference > 0.0) != inside(reference);
                let (from, to) = if forward { (e1, e2) } else { (e2, e1) };
                assert_eq!(next_edge[from], usize::MAX, "case {config}: edge {from} leaves twice");
                next_edge[from] = to;
            }
        }
    }
    let mut loops = Vec::new();
    let mut visited = [false; 12];
    for start in 0..12 {
        if next_edge[start] == usize::MAX || visited[start] {
            continue;
        }
        let mut polygon = Vec::new();
        let mut e = start;
        while !visited[e] {
            visited[e] = true;
            polygon.push(e as u8);
            e = next_edge[e];
        }
        assert_eq!(e, start, "case {config}: boundary does not close");
        let n = polygon.len();
        let needs_center = (0..n).any(|a| {
            (a + 2..n).any(|b| {
                let adjacent = a == 0 && b == n - 1;
                let (fa, fb) = (faces_of_edge(polygon[a] as usize), faces_of_edge(polygon[b] as usize));
                !adjacent && fa.iter().any(|f| fb.contains(f))
            })
        });
        loops.push(CaseLoop {
            edges: polygon,
            needs_center,
        });
    }
    loops
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_crossing_edge_is_on_exactly_one_loop() {
        let table = case_table();
        assert!(table[0].is_empty());
        assert!(table[255].is_empty());
        for config in 1..255usize {
            let loops = &table[config];
            assert!(!loops.is_empty(), "case {config}");
            // Every crossing edge is used once, no other edge is.
            let mut used = [false; 12];
            for l in loops {
                assert!(l.edges.len() >= 3);
                for &e in &l.edges {
                    assert!(!used[e as usize]);
                    used[e as usize] = true;
                }
            }
            for (e, &[a, b]) in EDGE_CORNERS.iter().enumerate() {
                let crosses = ((config >> a) & 1) != ((config >> b) & 1);
                assert_eq!(used[e], crosses, "case {config} edge {e}");
            }
        }
        // A single inside corner gives one triangle; only ambiguous cases need a centre vertex.
        assert_eq!(table[1].len(), 1);
        assert_eq!(table[1][0].fan().count(), 1);
        assert!(!table[0b0000_1111][0].needs_center);
        assert!(table.iter().flatten().any(|l| l.needs_center));
    }
}
