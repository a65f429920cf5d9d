//! Depth from the images, once in stage 1 (`maps.photo_depth`): at that fraction of the run, the
//! pixels a depth sensor lost in front of what it sensed (flying pixels dropped as low
//! confidence: a lamp pole, chandelier rods, table legs narrower than a grid cell) are swept
//! against their neighbour views at the poses corrected so far ([`i2sdf_data::photo_depth`]).
//! A depth found is dropped where the field already explains the pixel (`maps.photo_depth_explained`):
//! it renders the pixel well behind the depth and in the pixel's colour, so the pixel sees past
//! whatever the depth would put there (a halo of the edge support). Each depth kept becomes the
//! pixel's depth: the depth term, the bubble and inside points and the error-guided PDF maps
//! (initialised again from a fresh render) take it like the sensor's.
//!
//! Once only, and late: the sweep compares single pixels, so it waits for the pose correction
//! (from half of stage 1) to bring the poses within a fraction of a pixel — with the given poses
//! of a phone capture (1 cm / 0.5°, about a pixel) it finds a third as many of the lamp pole's
//! pixels (docs/results.md). The depths found are trainer state in the checkpoint
//! (`adam.photo_depth.value`), so a resumed run continues with the same ones.

use super::{PdfValues, Stage1};
use i2sdf_data::photo_depth::{photo_depth, PhotoDepthParams, PhotoView};
use i2sdf_data::{Camera, ImageF32};

/// The checkpoint's prefix of the depths found, and its metadata key saying they are there.
pub(super) const PHOTO_PREFIX: &str = "adam.photo_depth";
pub(super) const PHOTO_META: &str = "photo_depth";

impl Stage1 {
    /// The iteration at which the sweep runs: at `fraction` of stage 1 (`TrainingMaps::photo_depth`,
    /// which is 0 for exact depth); `None` without depth or when off.
    pub(super) fn photo_depth_at(config: &crate::config::TrainConfig, fraction: f32, no_depth: bool) -> Option<u64> {
        (fraction > 0.0 && !no_depth).then(|| (fraction as f64 * config.iterations() as f64).round() as u64)
    }

    /// Is the sweep due before the next step?
    pub fn needs_photo_depth(&self) -> bool {
        self.photo_depth.is_none() && self.photo_depth_at.is_some_and(|at| self.iteration >= at)
    }

    /// Runs the sweep at the current poses, drops the depths the field already explains
    /// (`maps.photo_depth_explained`) and gives every pixel left its depth; the PDF maps, if the
    /// bubble step has them, are initialised again over the pixels with depth. Returns the pixels
    /// given a depth and those dropped as explained.
    pub(super) fn sweep_photo_depth(&mut self) -> (usize, usize) {
        let scale = self.normalization.scale;
        let cameras: Vec<Camera> = self
            .given_views
            .iter()
            .enumerate()
            .map(|(i, v)| match &self.poses {
                Some(p) => Camera {
                    c2w: p.corrected_c2w(i, v.camera.c2w, &self.normalization),
                    ..v.camera.clone()
                },
                None => v.camera.clone(),
            })
            .collect();
        let rgb: Vec<ImageF32> = self
            .images
            .iter()
            .map(|im| ImageF32::from_data(im.width, im.height, 3, im.rgb.iter().flatten().copied().collect()))
            .collect();
        // Depth as the sensor's z-depth in world units (the images hold the distance along the
        // unit ray in normalized units).
        let depth: Vec<ImageF32> = self
            .images
            .iter()
            .map(|im| {
                let z = im
                    .depth
                    .iter()
                    .zip(&im.cos)
                    .map(|(t, c)| (*t as f64 * *c as f64 * scale) as f32);
                ImageF32::from_data(im.width, im.height, 1, z.collect())
            })
            .collect();
        let views: Vec<PhotoView> = cameras
            .iter()
            .zip(&rgb)
            .zip(&depth)
            .zip(&self.given_views)
            .map(|(((camera, rgb), depth), given)| PhotoView {
                camera,
                rgb,
                depth,
                low: given.depth_low.as_ref(),
            })
            .collect();
        let all: Vec<usize> = (0..views.len()).collect();
        let found = photo_depth(&views, &all, &PhotoDepthParams::default());
        let mut values = Vec::with_capacity(self.images.iter().map(|im| im.pixels()).sum());
        let tolerance = self.config.maps.photo_depth_explained;
        let mut explained = 0;
        for (im, pd) in self.images.iter().zip(found) {
            let at = values.len();
            match pd {
                Some(pd) => values.extend(pd.depth.data.iter().zip(&im.cos).map(|(z, c)| {
                    if *z > 0.0 {
                        (*z as f64 / *c as f64 / scale) as f32
                    } else {
                        0.0
                    }
                })),
                None => values.extend(std::iter::repeat(0.0).take(im.pixels())),
            }
            if tolerance > 0.0 {
                let view = &mut values[at..];
                let pixels: Vec<usize> = (0..im.pixels())
                    .filter(|&p| view[p] > 0.0 && im.depth[p] <= 0.0)
                    .collect();
                let t: Vec<f32> = pixels.iter().map(|&p| view[p]).collect();
                let drop = explained_by_field(&self.scene, &self.settings, im, &pixels, &t, tolerance);
                for (&p, _) in pixels.iter().zip(&drop).filter(|(_, d)| **d) {
                    view[p] = 0.0;
                    explained += 1;
                }
            }
        }
        let n = self.add_photo_depth(values);
        if self.pdf.is_some() {
            self.init_pdf();
        }
        (n, explained)
    }

    /// Gives the pixels without depth the depths `values` (per pixel, image after image; 0: none)
    /// and keeps them for the checkpoint. Returns how many pixels took one.
    pub(super) fn add_photo_depth(&mut self, values: Vec<f32>) -> usize {
        let mut at = 0;
        let mut n = 0;
        for im in &mut self.images {
            let pixels = im.pixels();
            for (d, v) in im.depth.iter_mut().zip(&values[at..at + pixels]) {
                if *d <= 0.0 && *v > 0.0 {
                    *d = *v;
                    n += 1;
                }
            }
            at += pixels;
        }
        self.photo_depth = Some(PdfValues(values));
        n
    }
}

/// A depth from the images is explained away where the field's render of its pixel lies over
/// this many times as far (and matches the pixel's colour, `maps.photo_depth_explained`). On seed
/// 1's capture at the sweep, the halos' render lies a median 1.19 times as far, as do the thin
/// objects' (the depths found are the ones the field lacks); the colour tells them apart
/// (docs/results.md, "Depths the field already explains").
pub const EXPLAINED_RATIO: f32 = 1.1;

/// What the field already explains: per pixel of `pixels` with a depth from the images `t`
/// (distance along the pixel's ray, normalized units), the field's own render of the pixel — its
/// depth as a multiple of `t` and the mean absolute difference of its colour from the image's.
/// A halo depth (the edge support puts an object's depth on a pixel whose ray passes the object
/// by) shows as a render far behind it that already matches the pixel's colour; a thin object the
/// field lost shows as a render behind it whose colour is the background's, not the pixel's.
pub fn field_render_at(
    scene: &i2sdf_model::NeuralScene,
    settings: &i2sdf_model::renderer::RenderSettings,
    im: &super::rays::TrainImage,
    pixels: &[usize],
    t: &[f32],
) -> Vec<(f32, f32)> {
    let mut ws = i2sdf_model::renderer::RenderWorkspace::default();
    let mut out = Vec::with_capacity(pixels.len());
    for (chunk, tc) in pixels.chunks(1024).zip(t.chunks(1024)) {
        let (origins, dirs): (Vec<[f32; 3]>, Vec<[f32; 3]>) = chunk.iter().map(|&p| im.ray(p)).unzip();
        i2sdf_model::renderer::forward::<rand_pcg::Pcg64>(scene, settings, &origins, &dirs, &[], &mut ws, None);
        for (j, (&p, &tp)) in chunk.iter().zip(tc).enumerate() {
            let c = &ws.out.rgb[3 * j..3 * j + 3];
            let o = im.rgb[p];
            let err = ((c[0] - o[0]).abs() + (c[1] - o[1]).abs() + (c[2] - o[2]).abs()) / 3.0;
            out.push((ws.out.depth[j] / tp, err));
        }
    }
    out
}

/// Per pixel of `pixels` with a depth from the images `t`: is it explained away, its pixel
/// rendered over [`EXPLAINED_RATIO`] times as far with the pixel's colour within `tolerance`?
pub fn explained_by_field(
    scene: &i2sdf_model::NeuralScene,
    settings: &i2sdf_model::renderer::RenderSettings,
    im: &super::rays::TrainImage,
    pixels: &[usize],
    t: &[f32],
    tolerance: f32,
) -> Vec<bool> {
    field_render_at(scene, settings, im, pixels, t)
        .into_iter()
        .map(|(ratio, err)| is_explained(ratio, err, EXPLAINED_RATIO, tolerance))
        .collect()
}

/// The rule of [`explained_by_field`] on one pixel's render ([`field_render_at`]: its depth as
/// a multiple of the depth found, its colour error): rendered over `ratio_min` times as far, in
/// the pixel's colour within `tolerance`.
pub fn is_explained(ratio: f32, err: f32, ratio_min: f32, tolerance: f32) -> bool {
    ratio > ratio_min && err < tolerance
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage1::rays::TrainImage;
    use i2sdf_data::Normalization;
    use i2sdf_model::renderer::RenderSettings;

    /// A camera at the centre of the untrained field (an inverted sphere of radius 0.7) with two
    /// pixels looking at its wall; the images' colours as the field renders them, unless changed.
    /// Also gives the rendered depths (the untrained field's density is soft: ~0.8, not 0.7).
    fn setup() -> (i2sdf_model::NeuralScene, RenderSettings, TrainImage, [f32; 2]) {
        let model = i2sdf_model::config::ModelConfig {
            hash_levels: 4,
            hash_log2_table: 12,
            hash_finest_resolution: 64,
            init_radius: 0.7,
            ..Default::default()
        };
        let norm = Normalization {
            center: [0.0; 3],
            scale: 1.0,
        };
        let scene = i2sdf_model::NeuralScene::new(&model, norm, 1);
        let settings = RenderSettings::default();
        let mut im = TrainImage {
            frame_index: 0,
            width: 2,
            height: 1,
            origin: [0.0; 3],
            dirs: vec![[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]],
            cos: vec![1.0; 2],
            rgb: vec![[0.0; 3]; 2],
            depth: vec![0.0; 2],
            normal: None,
            emitter: None,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        };
        let mut ws = i2sdf_model::renderer::RenderWorkspace::default();
        let (o, d): (Vec<_>, Vec<_>) = (0..2).map(|p| im.ray(p)).unzip();
        i2sdf_model::renderer::forward::<rand_pcg::Pcg64>(&scene, &settings, &o, &d, &[], &mut ws, None);
        for p in 0..2 {
            im.rgb[p].copy_from_slice(&ws.out.rgb[3 * p..3 * p + 3]);
            assert!((0.6..1.0).contains(&ws.out.depth[p]), "the wall at {}", ws.out.depth[p]);
        }
        let wall = [ws.out.depth[0], ws.out.depth[1]];
        (scene, settings, im, wall)
    }

    /// A depth halfway to the wall on a pixel whose colour the field renders is a halo and goes;
    /// the same depth on a pixel whose colour the field gets wrong (a thin object it lost) stays,
    /// and so does a depth at the wall the field renders.
    #[test]
    fn depths_the_field_already_explains_are_dropped_and_the_ones_it_lacks_kept() {
        let (scene, settings, mut im, wall) = setup();
        let halfway = wall.map(|d| d / 2.0);
        assert_eq!(
            explained_by_field(&scene, &settings, &im, &[0, 1], &halfway, 0.02),
            [true, true]
        );
        im.rgb[1] = im.rgb[1].map(|c| (c + 0.3).min(1.0) - if c > 0.7 { 0.6 } else { 0.0 });
        assert_eq!(
            explained_by_field(&scene, &settings, &im, &[0, 1], &halfway, 0.02),
            [true, false]
        );
        assert_eq!(
            explained_by_field(&scene, &settings, &im, &[0], &[wall[0] * 0.98], 0.02),
            [false]
        );
        let r = field_render_at(&scene, &settings, &im, &[0, 1], &halfway);
        assert!((r[0].0 - 2.0).abs() < 0.15 && r[0].1 < 1e-4, "{r:?}");
        assert!(r[1].1 > 0.25, "{r:?}");
    }
}
