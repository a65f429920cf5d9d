//! Training rays: the training pixels of a dataset as rays in the normalized frame (the scene inside
//! the unit sphere) with their supervision — LDR colour, depth as distance along the unit ray, the
//! world normal (the normalization is a similarity without rotation, so normals do not change) and
//! the emitter mask, as [`TrainingMaps`] says (the dataset's, or what stands in for them).

use crate::maps::TrainingMaps;
use i2sdf_data::{Dataset, Frame, ImageF32, Normalization, Split};
use rand::Rng;

/// One image's supervision in flat per-pixel arrays, ready for random access.
pub struct TrainImage {
    pub frame_index: usize,
    pub width: usize,
    pub height: usize,
    /// Per pixel: ray origin is the camera centre (normalized); direction unit, normalized frame.
    pub origin: [f32; 3],
    pub dirs: Vec<[f32; 3]>,
    /// Per pixel: cos θ between ray and optical axis (z-depth = t · cos θ).
    pub cos: Vec<f32>,
    pub rgb: Vec<[f32; 3]>,
    /// Depth as distance along the unit ray in normalized units; 0 where there is none.
    pub depth: Vec<f32>,
    pub normal: Option<Vec<[f32; 3]>>,
    pub emitter: Option<Vec<f32>>,
    /// The pose correction in use (row-major rotation about the camera centre, translation;
    /// identity unless stage 1 corrects the poses): every ray and surface point of the image
    /// goes through it.
    pub rotation: [[f32; 3]; 3],
    pub translation: [f32; 3],
}

impl TrainImage {
    /// `frame`'s supervision, with `normal` and `emitter` the maps training uses for it.
    pub fn new(
        frame_index: usize,
        frame: &Frame,
        norm: &Normalization,
        normal: Option<&ImageF32>,
        emitter: Option<&ImageF32>,
    ) -> Self {
        let cam = &frame.camera;
        let (w, h) = (cam.width, cam.height);
        let o = norm.to_normalized(cam.center());
        let mut dirs = Vec::with_capacity(w * h);
        let mut cos = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let (_, d, c) = cam.ray(i as f64 + 0.5, j as f64 + 0.5);
                dirs.push([d.x as f32, d.y as f32, d.z as f32]);
                cos.push(c as f32);
            }
        }
        let rgb = frame.rgb.data.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let depth = match &frame.depth {
            Some(d) => d
                .data
                .iter()
                .zip(&cos)
                .map(|(z, c)| {
                    if *z > 0.0 {
                        (*z as f64 / *c as f64 / norm.scale) as f32
                    } else {
                        0.0
                    }
                })
                .collect(),
            None => vec![0.0; w * h],
        };
        let normal = normal.map(|n| n.data.chunks(3).map(|c| [c[0], c[1], c[2]]).collect());
        let emitter = emitter.map(|m| m.data.clone());
        TrainImage {
            frame_index,
            width: w,
            height: h,
            origin: [o.x as f32, o.y as f32, o.z as f32],
            dirs,
            cos,
            rgb,
            depth,
            normal,
            emitter,
            rotation: IDENTITY,
            translation: [0.0; 3],
        }
    }

    /// The corrected ray of a pixel: origin and unit direction, normalized frame.
    #[inline]
    pub fn ray(&self, pixel: usize) -> ([f32; 3], [f32; 3]) {
        let o = self.origin;
        let t = self.translation;
        let d = self.dirs[pixel];
        let r = &self.rotation;
        (
            [o[0] + t[0], o[1] + t[1], o[2] + t[2]],
            std::array::from_fn(|i| r[i][0] * d[0] + r[i][1] * d[1] + r[i][2] * d[2]),
        )
    }

    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// The surface point seen at a pixel according to its depth (paper eq:unproj), normalized frame.
    pub fn surface_point(&self, pixel: usize) -> Option<[f32; 3]> {
        let t = self.depth[pixel];
        (t > 0.0).then(|| self.point_along(pixel, t))
    }

    /// The point at distance `t` along a pixel's corrected ray.
    #[inline]
    pub fn point_along(&self, pixel: usize, t: f32) -> [f32; 3] {
        let (o, d) = self.ray(pixel);
        [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]
    }

    /// The point at distance `t` along a pixel's ray at the corrected pose, or with `given` at
    /// the given one (no correction).
    #[inline]
    pub fn point_at(&self, pixel: usize, t: f32, given: bool) -> [f32; 3] {
        if !given {
            return self.point_along(pixel, t);
        }
        let (o, d) = (self.origin, self.dirs[pixel]);
        [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]
    }

    /// The depth map's point of a pixel at the corrected pose, or with `given` at the given one.
    pub fn depth_point(&self, pixel: usize, given: bool) -> Option<[f32; 3]> {
        let t = self.depth[pixel];
        (t > 0.0).then(|| self.point_at(pixel, t, given))
    }
}

const IDENTITY: [[f32; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// All training images of a dataset, with the maps in force.
pub fn train_images(ds: &Dataset, maps: &TrainingMaps) -> Vec<TrainImage> {
    ds.frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.split == Split::Train)
        .map(|(i, f)| {
            TrainImage::new(
                i,
                f,
                &ds.normalization,
                maps.normal(f).as_deref(),
                maps.emitter_mask(i, f),
            )
        })
        .collect()
}

/// A batch of rays with their supervision, structure-of-arrays.
#[derive(Default)]
pub struct RayBatch {
    pub image: Vec<u32>,
    pub pixel: Vec<u32>,
    pub origin: Vec<[f32; 3]>,
    pub dir: Vec<[f32; 3]>,
    pub rgb: Vec<[f32; 3]>,
    pub depth: Vec<f32>,
    pub has_depth: Vec<bool>,
    pub normal: Vec<[f32; 3]>,
    pub has_normal: Vec<bool>,
    pub emitter: Vec<f32>,
    pub has_emitter: bool,
}

impl RayBatch {
    pub fn len(&self) -> usize {
        self.origin.len()
    }
    pub fn is_empty(&self) -> bool {
        self.origin.is_empty()
    }

    pub fn clear(&mut self) {
        self.image.clear();
        self.pixel.clear();
        self.origin.clear();
        self.dir.clear();
        self.rgb.clear();
        self.depth.clear();
        self.has_depth.clear();
        self.normal.clear();
        self.has_normal.clear();
        self.emitter.clear();
    }

    pub fn push(&mut self, images: &[TrainImage], image: usize, pixel: usize) {
        let im = &images[image];
        self.image.push(image as u32);
        self.pixel.push(pixel as u32);
        let (o, d) = im.ray(pixel);
        self.origin.push(o);
        self.dir.push(d);
        self.rgb.push(im.rgb[pixel]);
        self.depth.push(im.depth[pixel]);
        self.has_depth.push(im.depth[pixel] > 0.0);
        // A given normal turns with its view's correction (it was made in that view's frame).
        let n = im.normal.as_ref().map_or([0.0; 3], |n| {
            let n = n[pixel];
            let r = &im.rotation;
            std::array::from_fn(|i| r[i][0] * n[0] + r[i][1] * n[1] + r[i][2] * n[2])
        });
        self.normal.push(n);
        self.has_normal.push(n != [0.0; 3]);
        self.emitter.push(im.emitter.as_ref().map_or(0.0, |e| e[pixel]));
    }

    /// Fills the batch with `n` pixels drawn uniformly over all training pixels.
    pub fn sample_uniform(&mut self, images: &[TrainImage], n: usize, rng: &mut impl Rng) {
        self.clear();
        self.add_uniform(images, n, rng);
    }

    /// Adds `n` pixels drawn uniformly over all training pixels.
    pub fn add_uniform(&mut self, images: &[TrainImage], n: usize, rng: &mut impl Rng) {
        let total: usize = images.iter().map(|i| i.pixels()).sum();
        self.has_emitter = images.iter().all(|i| i.emitter.is_some());
        for _ in 0..n {
            let mut k = rng.gen_range(0..total);
            let mut image = 0;
            while k >= images[image].pixels() {
                k -= images[image].pixels();
                image += 1;
            }
            self.push(images, image, k);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_data::fixture::{self, FixtureOptions};
    use i2sdf_model::renderer::sphere_exit;
    use rand::SeedableRng;

    #[test]
    fn depth_supervision_lands_on_the_surface() {
        let dir = tempfile::tempdir().unwrap();
        fixture::write_native(dir.path(), &FixtureOptions::default());
        let ds = i2sdf_data::load(dir.path()).unwrap();
        let maps = TrainingMaps::prepare(&ds, &Default::default()).unwrap();
        let images = train_images(&ds, &maps);
        assert_eq!(images.len(), 4);
        // Every depth pixel's surface point maps back (in world units) onto a wall of the room.
        for im in &images {
            for p in 0..im.pixels() {
                let q = im.surface_point(p).unwrap();
                let w = ds
                    .normalization
                    .to_world(glam::DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64));
                let to_wall = (0..3)
                    .map(|a| {
                        (w[a] - fixture::ROOM_MIN[a])
                            .abs()
                            .min((w[a] - fixture::ROOM_MAX[a]).abs())
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(to_wall < 1e-4, "{w:?}");
                assert!(sphere_exit(im.origin, im.dirs[p], 1.0) >= im.depth[p]);
            }
        }
        // A corrected view: its depth points move with the correction, the pinned ones do not.
        let mut images = images;
        let im = &mut images[0];
        let p = im.pixels() / 2;
        let given = im.depth_point(p, true).unwrap();
        assert_eq!(given, im.surface_point(p).unwrap());
        im.translation = [0.01, -0.02, 0.0];
        im.rotation = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
        assert_eq!(im.depth_point(p, true).unwrap(), given);
        let moved = im.depth_point(p, false).unwrap();
        assert!((0..3).map(|k| (moved[k] - given[k]).abs()).sum::<f32>() > 0.01);
        let mut batch = RayBatch::default();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
        batch.sample_uniform(&images, 100, &mut rng);
        assert_eq!(batch.len(), 100);
        assert!(batch.has_emitter && batch.has_depth.iter().all(|v| *v));
    }
}
