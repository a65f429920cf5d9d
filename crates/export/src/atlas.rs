//! The UV atlas the material fields are baked into: `uvunwrap` cuts the simplified surface into
//! charts, flattens each (LSCM, evened out by ARAP) and packs them into one atlas page. Its
//! output vertices are the input's, split along the charts' seams (each knows the input vertex
//! it came from); its faces are the input's, in the same order.

use i2sdf_data::DataError;

/// Charts of a mesh packed into one `width` × `height` atlas.
#[derive(Clone, Debug, PartialEq)]
pub struct UvAtlas {
    pub width: u32,
    /// `width`: the page is kept square (a power of two where the width is one, which older
    /// viewers need for mipmaps) though the charts may use fewer rows.
    pub height: u32,
    /// Per output vertex: its input vertex.
    pub xref: Vec<u32>,
    /// Per output vertex: its texture coordinate in [0, 1]² of the page, glTF's convention (u
    /// along a row, v down from the image's first row). Vertices of ignored faces only sit on a
    /// charted vertex's uv (or at (0, 0)).
    pub uv: Vec<[f32; 2]>,
    /// The input faces over the output vertices, in the input's order.
    pub faces: Vec<[u32; 3]>,
    /// Texels per world unit the charts were packed at.
    pub texels_per_unit: f32,
    pub charts: usize,
    /// Fraction of the page's texels the charts cover.
    pub utilization: f32,
}

/// Unwraps `faces` over `positions` into one atlas page `size` texels wide, `padding` texels
/// around each chart. Faces flagged in `ignore` get no chart.
pub fn unwrap(
    positions: &[[f32; 3]],
    faces: &[[u32; 3]],
    ignore: &[bool],
    size: u32,
    padding: u32,
) -> Result<UvAtlas, DataError> {
    assert_eq!(ignore.len(), faces.len(), "one ignore flag per face");
    let indices: Vec<u32> = faces.iter().flatten().copied().collect();
    let mesh = uvunwrap::MeshInput {
        ignored_faces: Some(ignore),
        ..uvunwrap::MeshInput::new(positions, &indices)
    };
    let options = uvunwrap::Options {
        density: uvunwrap::Density::Auto { page_size: size },
        padding,
        ..Default::default()
    };
    let atlas = uvunwrap::generate(&[mesh], &options).map_err(|e| {
        DataError::invalid(format!(
            "the surface could not be unwrapped into a {size}-texel atlas: {e}"
        ))
    })?;
    if atlas.page_count > 1 {
        return Err(DataError::invalid(format!(
            "the surface's {} charts do not fit one {size}-texel atlas page: ask for a larger --texture-size",
            atlas.chart_count
        )));
    }
    let out = &atlas.meshes[0];
    // uvunwrap crops the page to the rows its charts use: back to a square page
    let v_scale = atlas.height as f32 / atlas.width as f32;
    Ok(UvAtlas {
        width: atlas.width,
        height: atlas.width,
        xref: out.vertices.iter().map(|v| v.xref).collect(),
        uv: out.vertices.iter().map(|v| [v.uv[0], v.uv[1] * v_scale]).collect(),
        faces: out.indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        texels_per_unit: atlas.texels_per_unit,
        charts: atlas.chart_count as usize,
        utilization: atlas.utilization * v_scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed box of 12 triangles (a unit cube).
    fn cube() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let p: Vec<[f32; 3]> = (0..8)
            .map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
            .collect();
        #[rustfmt::skip]
        let f = vec![
            [0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
            [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5],
        ];
        (p, f)
    }

    fn uv_area(q: [[f32; 2]; 3]) -> f32 {
        0.5 * ((q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]))
    }

    #[test]
    fn a_cube_unwraps_into_non_overlapping_charts_that_keep_its_faces() {
        let (p, f) = cube();
        let a = unwrap(&p, &f, &[false; 12], 64, 2).unwrap();
        assert_eq!(a.faces.len(), 12);
        assert!(a.charts >= 1 && a.width == 64 && a.height == 64);
        // the same faces, in order, over split vertices
        for (fi, fo) in f.iter().zip(&a.faces) {
            for k in 0..3 {
                assert_eq!(a.xref[fo[k] as usize], fi[k]);
            }
        }
        // uv inside the page; each face's uv area in proportion to its world area (a cube's
        // charts are flat: no stretch)
        let (w, h) = (a.width as f32, a.height as f32);
        let mut areas = Vec::new();
        for fo in &a.faces {
            let q = fo.map(|v| {
                let [u, v] = a.uv[v as usize];
                [u * w, v * h]
            });
            assert!(fo
                .iter()
                .all(|&v| a.uv[v as usize].iter().all(|c| (0.0..=1.0).contains(c))));
            areas.push(uv_area(q).abs());
        }
        let mean = areas.iter().sum::<f32>() / 12.0;
        assert!(areas.iter().all(|&x| (x - mean).abs() < 0.02 * mean), "{areas:?}");
        // no texel centre inside two faces
        let n = 4 * a.width as usize;
        let m = 4 * a.height as usize;
        let mut claimed = vec![false; n * m];
        for fo in &a.faces {
            let q = fo.map(|v| a.uv[v as usize]);
            for y in 0..m {
                for x in 0..n {
                    let c = [(x as f32 + 0.5) / n as f32, (y as f32 + 0.5) / m as f32];
                    let s = |a: [f32; 2], b: [f32; 2]| (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
                    let d = [s(q[0], q[1]), s(q[1], q[2]), s(q[2], q[0])];
                    if d.iter().all(|&x| x > 0.0) || d.iter().all(|&x| x < 0.0) {
                        assert!(!claimed[y * n + x], "texel ({x}, {y}) in two faces");
                        claimed[y * n + x] = true;
                    }
                }
            }
        }
    }

    #[test]
    fn ignored_faces_get_no_uv_area() {
        let (p, f) = cube();
        let mut ignore = [false; 12];
        ignore[0] = true;
        ignore[1] = true;
        let a = unwrap(&p, &f, &ignore, 64, 2).unwrap();
        for fo in &a.faces[..2] {
            assert_eq!(uv_area(fo.map(|v| a.uv[v as usize])), 0.0);
        }
        assert!(a.faces[2..]
            .iter()
            .all(|fo| uv_area(fo.map(|v| a.uv[v as usize])).abs() > 0.0));
    }
}
