//! Depth from the images, once in stage 1 (`maps.photo_depth`): at that fraction of the run, the
//! pixels a depth sensor lost in front of what it sensed (flying pixels dropped as low
//! confidence: a lamp pole, chandelier rods, table legs narrower than a grid cell) are swept
//! against their neighbour views at the poses corrected so far ([`i2sdf_data::photo_depth`]).
//! Each depth found becomes the pixel's depth: the depth term, the bubble and inside points and
//! the error-guided PDF maps (initialised again from a fresh render) take it like the sensor's.
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

    /// Runs the sweep at the current poses and gives every pixel it found its depth; the PDF maps,
    /// if the bubble step has them, are initialised again over the pixels with depth. Returns the
    /// pixels given a depth.
    pub(super) fn sweep_photo_depth(&mut self) -> usize {
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
        for (im, pd) in self.images.iter().zip(found) {
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
        }
        let n = self.add_photo_depth(values);
        if self.pdf.is_some() {
            self.init_pdf();
        }
        n
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
