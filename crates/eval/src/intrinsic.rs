//! Evaluating stage 2 (materials and emitters) on the test views: the Monte Carlo re-render of
//! eq:render tone-mapped with the dataset's transfer against the test LDR images, the material
//! maps (Kd, ρ of the pixel-centre rays) against the GT maps (where the material mask, if any,
//! says GGX), and the emitters found against the dataset's GT emitters. The frozen scene is the
//! run's as stage 2 built it ([`i2sdf_model::OpenedRun::frozen`]); the images come from
//! [`i2sdf_model::images`].

use crate::image_metrics::{psnr, psnr_from_mse, ssim, ImageRef};
use crate::report::{EmitterMatch, EmitterMetrics, MaterialMetrics, RerenderMetrics};
use glam::{DVec3, Vec3};
use i2sdf_data::dataset::GtEmitter;
use i2sdf_data::{DataError, Dataset, Frame, ImageF32, Split};
use i2sdf_model::images::rerender_ldr;
use i2sdf_model::intrinsic_io::IntrinsicFields;
use i2sdf_model::{rerender_view, EmitterTable, FrozenScene};
use i2sdf_render::{luminance, ViewRender};

/// Options of [`intrinsic_metrics`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntrinsicOptions {
    /// Paths per pixel of the re-render.
    pub spp: u32,
    pub seed: u64,
    /// Denoise the re-render before scoring it ([`i2sdf_render::denoise`]).
    pub denoise: Option<i2sdf_render::Denoiser>,
}

impl Default for IntrinsicOptions {
    fn default() -> Self {
        IntrinsicOptions {
            spp: 64,
            seed: 0,
            denoise: None,
        }
    }
}

/// The pixels the material metrics compare: the re-render hit a surface (finite depth), the
/// pixel is not an emitter — by the dataset's emitter mask (value > 0.5, first channel) where it
/// has one, else by the re-render's — and the dataset's material mask, where it has one, does not
/// mark the pixel's material as one GGX cannot fit (value ≤ 0.5: `Frame::material_mask`).
pub fn material_mask(
    depth: &[f32],
    gt_emitter: Option<&ImageF32>,
    pred_emitter: &[bool],
    gt_material: Option<&ImageF32>,
) -> Vec<bool> {
    (0..depth.len())
        .map(|i| {
            let emitter = match gt_emitter {
                Some(m) => m.data[i * m.channels] > 0.5,
                None => pred_emitter[i],
            };
            let ggx = gt_material.is_none_or(|m| m.data[i * m.channels] > 0.5);
            depth[i].is_finite() && !emitter && ggx
        })
        .collect()
}

/// Sums over views for the material metrics: per channel Σ p·g, Σ p², Σ g², and Σ (p − g)² of
/// the albedo; Σ |ρ − ρ_gt| of the roughness. Non-finite GT values are skipped.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialAccumulator {
    pg: [f64; 3],
    pp: [f64; 3],
    gg: [f64; 3],
    se: f64,
    albedo_pixels: usize,
    rough_abs: f64,
    rough_pixels: usize,
    /// The same over the pixels with a specular lobe (GT Ks luminance ≥ [`LOBE_KS`]).
    lobe_abs: f64,
    lobe_pixels: usize,
}

/// GT Ks luminance from which a pixel counts in `MaterialMetrics::roughness_l1_lobe`: below it
/// the lobe is a fraction of the 4 % of a common dielectric and ρ hardly changes the pixel.
pub const LOBE_KS: f32 = 0.01;

impl MaterialAccumulator {
    /// Adds a view's Kd (per pixel) against its GT albedo (3 channels) over `mask`.
    pub fn add_albedo(&mut self, pred: &[Vec3], gt: &[f32], mask: &[bool]) {
        for (i, p) in pred.iter().enumerate() {
            let g = &gt[i * 3..i * 3 + 3];
            if !mask[i] || !g.iter().all(|x| x.is_finite()) {
                continue;
            }
            for c in 0..3 {
                let (p, g) = (p[c] as f64, g[c] as f64);
                self.pg[c] += p * g;
                self.pp[c] += p * p;
                self.gg[c] += g * g;
                self.se += (p - g) * (p - g);
            }
            self.albedo_pixels += 1;
        }
    }

    /// Adds a view's roughness against its GT roughness (first channel of `gt`, `channels` per
    /// pixel) over `mask`; `gt_ks` (the GT Ks map and its channels per pixel, where the dataset
    /// has one) also counts the pixels with a lobe apart.
    pub fn add_roughness(
        &mut self,
        pred: &[f32],
        gt: &[f32],
        channels: usize,
        mask: &[bool],
        gt_ks: Option<(&[f32], usize)>,
    ) {
        for (i, p) in pred.iter().enumerate() {
            let g = gt[i * channels];
            if mask[i] && g.is_finite() {
                let e = (*p as f64 - g as f64).abs();
                self.rough_abs += e;
                self.rough_pixels += 1;
                if let Some((ks, c)) = gt_ks {
                    let k = &ks[i * c..(i + 1) * c];
                    let lum = if c >= 3 {
                        luminance(Vec3::new(k[0], k[1], k[2]))
                    } else {
                        k[0]
                    };
                    if lum >= LOBE_KS {
                        self.lobe_abs += e;
                        self.lobe_pixels += 1;
                    }
                }
            }
        }
    }

    /// Per-channel least-squares scale of the prediction onto the GT: s_c = Σ p·g / Σ p² (1 where
    /// the prediction is all zero).
    pub fn scale(&self) -> [f64; 3] {
        std::array::from_fn(|c| if self.pp[c] > 0.0 { self.pg[c] / self.pp[c] } else { 1.0 })
    }

    /// The metrics (PSNR capped at 100 dB, as the novel-view figures); `None` where no pixel was
    /// compared.
    pub fn finish(&self) -> MaterialMetrics {
        let n = self.albedo_pixels;
        let (albedo_psnr, albedo_psnr_scaled, albedo_scale) = if n > 0 {
            let s = self.scale();
            let se_scaled: f64 = (0..3)
                .map(|c| (s[c] * s[c] * self.pp[c] - 2.0 * s[c] * self.pg[c] + self.gg[c]).max(0.0))
                .sum();
            let db = |se: f64| psnr_from_mse(se / (3 * n) as f64).min(100.0);
            (Some(db(self.se)), Some(db(se_scaled)), Some(s))
        } else {
            (None, None, None)
        };
        MaterialMetrics {
            albedo_psnr,
            albedo_psnr_scaled,
            roughness_l1: (self.rough_pixels > 0).then(|| self.rough_abs / self.rough_pixels as f64),
            albedo_scale,
            pixels: (n > 0).then_some(n),
            albedo_psnr_seen: None,
            seen_fraction: None,
            roughness_l1_lobe: (self.lobe_pixels > 0).then(|| self.lobe_abs / self.lobe_pixels as f64),
            lobe_fraction: (self.lobe_pixels > 0 && self.rough_pixels > 0)
                .then(|| self.lobe_pixels as f64 / self.rough_pixels as f64),
        }
    }
}

/// Training views that must see a test pixel's surface for it to count in
/// `MaterialMetrics::albedo_psnr_seen`.
pub const SEEN_BY: u8 = 2;

/// Per pixel of `frame`, how many training views of `dataset` see the surface at its depth
/// (saturating at 255): the pixel's GT depth point projected into each training view lands in
/// its image where that view's depth agrees within 2 %. `None` unless the depth is exact (the
/// dataset declares `depth_exact`) and `frame` and every training view have it: sensor depth is
/// too sparse and noisy to say what a view sees.
pub fn training_views_seeing(dataset: &Dataset, frame: &Frame) -> Option<Vec<u8>> {
    if !dataset.depth_exact {
        return None;
    }
    let depth = frame.depth.as_ref()?;
    let train: Vec<(&i2sdf_data::Camera, &ImageF32)> = dataset
        .split(Split::Train)
        .map(|f| Some((&f.camera, f.depth.as_ref()?)))
        .collect::<Option<_>>()?;
    let w = frame.camera.width;
    Some(
        depth
            .data
            .iter()
            .step_by(depth.channels)
            .enumerate()
            .map(|(i, &z)| {
                if !(z > 0.0 && z.is_finite()) {
                    return 0;
                }
                let x = frame.camera.backproject(i % w, i / w, z as f64);
                let seen = train.iter().filter(|(cam, d)| {
                    let Some((u, v, zc)) = cam.project(x) else { return false };
                    if !(u >= 0.0 && v >= 0.0 && (u as usize) < d.width && (v as usize) < d.height) {
                        return false;
                    }
                    let dz = d.data[(v as usize * d.width + u as usize) * d.channels] as f64;
                    (dz - zc).abs() < 0.02 * zc
                });
                seen.count().min(255) as u8
            })
            .collect(),
    )
}

/// Distance from a point to an axis-aligned box, 0 inside.
pub fn distance_to_box(p: [f64; 3], min: [f64; 3], max: [f64; 3]) -> f64 {
    (0..3)
        .map(|a| (min[a] - p[a]).max(0.0).max(p[a] - max[a]))
        .map(|d| d * d)
        .sum::<f64>()
        .sqrt()
}

/// The emitters of the table (count, centres, L\[k\]) and, where `gt` lists GT emitters, the
/// nearest predicted emitter to each with the ratio of its L\[k\] to the GT emission × exposure
/// (L\[k\] is in linear image units, exposure × physical radiance; exposure 1 when `None`).
pub fn emitter_metrics(table: &EmitterTable, gt: &[GtEmitter], exposure: Option<f64>) -> EmitterMetrics {
    let exposure = exposure.unwrap_or(1.0);
    let emission: Vec<[f64; 3]> = (0..table.len())
        .map(|k| table.emission(k).as_dvec3().to_array())
        .collect();
    let matches = (!gt.is_empty()).then(|| {
        gt.iter()
            .map(|g| {
                let box_centre = DVec3::from_array(g.bounds_min).lerp(DVec3::from_array(g.bounds_max), 0.5);
                let key = |k: usize| {
                    let c = table.emitters[k].centre;
                    (
                        distance_to_box(c, g.bounds_min, g.bounds_max),
                        DVec3::from_array(c).distance(box_centre),
                    )
                };
                let best = (0..table.len()).min_by(|&a, &b| {
                    let (ka, kb) = (key(a), key(b));
                    ka.0.total_cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
                });
                let want = g.emission.map(|e| e * exposure);
                let ratio = |l: f64, w: f64| if w > 0.0 { Some(l / w) } else { None };
                let (emission_ratio, emission_ratio_mean) = match best {
                    Some(k) => {
                        let l = emission[k];
                        let per: Option<Vec<f64>> = (0..3).map(|c| ratio(l[c], want[c])).collect();
                        (
                            per.map(|v| [v[0], v[1], v[2]]),
                            ratio(l.iter().sum(), want.iter().sum()),
                        )
                    }
                    None => (None, None),
                };
                EmitterMatch {
                    name: g.name.clone(),
                    predicted: best,
                    distance: best.map(|k| key(k).0),
                    emission_ratio,
                    emission_ratio_mean,
                }
            })
            .collect()
    });
    EmitterMetrics {
        count: Some(table.len()),
        centres: Some(table.emitters.iter().map(|e| e.centre).collect()),
        emission: Some(emission),
        matches,
    }
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn check_dims(f: &Frame, what: &str, img: &ImageF32, channels: usize) -> Result<(), DataError> {
    if img.width != f.camera.width || img.height != f.camera.height || img.channels < channels {
        return Err(DataError::file(
            &f.image_path,
            format!(
                "the {what} map is {}×{}×{}, the view {}×{} (at least {channels} channels wanted)",
                img.width, img.height, img.channels, f.camera.width, f.camera.height
            ),
        ));
    }
    Ok(())
}

/// Stage 2's metrics over the test views (see the module doc): each view re-rendered once in
/// `frozen` (the run's, [`i2sdf_model::OpenedRun::frozen`]) with `rerender_view` (`spp` paths per
/// pixel, the view's index in the test split as its sampler's). Rerender PSNR/SSIM are means over
/// views; material figures pool all test views; emitters come from the table and
/// `dataset.emitters`.
pub fn intrinsic_metrics(
    frozen: &FrozenScene,
    fields: &IntrinsicFields,
    dataset: &Dataset,
    options: &IntrinsicOptions,
) -> Result<(RerenderMetrics, MaterialMetrics, EmitterMetrics), DataError> {
    intrinsic_metrics_with_progress(frozen, fields, dataset, options, &|| {}, None)
}

/// [`intrinsic_metrics`], calling `on_row` after each rendered row (progress), and keeping each
/// test view's re-render in `keep` when given (`eval --renders` writes them).
pub fn intrinsic_metrics_with_progress(
    frozen: &FrozenScene,
    fields: &IntrinsicFields,
    dataset: &Dataset,
    options: &IntrinsicOptions,
    on_row: &(dyn Fn() + Sync),
    mut keep: Option<&mut Vec<ViewRender>>,
) -> Result<(RerenderMetrics, MaterialMetrics, EmitterMetrics), DataError> {
    let (mut p, mut s) = (Vec::new(), Vec::new());
    let mut acc = MaterialAccumulator::default();
    // The same over the pixels enough training views see (None: not measurable).
    let mut seen_acc = Some(MaterialAccumulator::default());
    for (view, f) in dataset.split(Split::Test).enumerate() {
        let (w, h) = (f.camera.width, f.camera.height);
        for (what, map, ch) in [
            ("albedo", &f.albedo, 3),
            ("roughness", &f.roughness, 1),
            ("specular", &f.specular, 1),
            ("emitter mask", &f.emitter_mask, 1),
            ("material mask", &f.material_mask, 1),
        ] {
            if let Some(m) = map {
                check_dims(f, what, m, ch)?;
            }
        }
        let mut v = rerender_view(
            frozen,
            &fields.material,
            &f.camera,
            options.spp,
            options.seed,
            view as u32,
            on_row,
        );
        if let Some(d) = &options.denoise {
            d.apply(&mut v);
        }
        let ldr = rerender_ldr(&v, &fields.radiometry);
        let pred = ImageRef::new(&ldr.data, w, h, 3)?;
        let gt = ImageRef::new(&f.rgb.data, w, h, 3)?;
        if let Some(x) = psnr(pred, gt, None)? {
            p.push(x.min(100.0));
        }
        if let Some(x) = ssim(pred, gt, None)? {
            s.push(x);
        }
        let mask = material_mask(
            &v.depth,
            f.emitter_mask.as_ref(),
            &v.emitter_mask,
            f.material_mask.as_ref(),
        );
        if let Some(a) = &f.albedo {
            let rgb: std::borrow::Cow<[f32]> = if a.channels == 3 {
                (&a.data[..]).into()
            } else {
                a.data.chunks(a.channels).flat_map(|c| [c[0], c[1], c[2]]).collect()
            };
            acc.add_albedo(&v.kd, &rgb, &mask);
            seen_acc = seen_acc.and_then(|mut sa| {
                let seen = training_views_seeing(dataset, f).filter(|s| s.len() == mask.len())?;
                let m: Vec<bool> = mask.iter().zip(&seen).map(|(m, s)| *m && *s >= SEEN_BY).collect();
                sa.add_albedo(&v.kd, &rgb, &m);
                Some(sa)
            });
        }
        if let Some(r) = &f.roughness {
            let ks = f.specular.as_ref().map(|k| (&k.data[..], k.channels));
            acc.add_roughness(&v.roughness, &r.data, r.channels, &mask, ks);
        }
        if let Some(keep) = keep.as_deref_mut() {
            keep.push(v);
        }
    }
    let rerender = RerenderMetrics {
        psnr: mean(&p),
        ssim: mean(&s),
        denoised: options.denoise.is_some(),
    };
    let emitters = emitter_metrics(&fields.emitters, &dataset.emitters, dataset.radiometry.exposure);
    let mut material = acc.finish();
    if let (Some(sa), Some(n)) = (seen_acc, material.pixels) {
        let seen = sa.finish();
        material.albedo_psnr_seen = seen.albedo_psnr;
        material.seen_fraction = Some(seen.pixels.unwrap_or(0) as f64 / n as f64);
    }
    Ok((rerender, material, emitters))
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_data::Radiometry;
    use i2sdf_model::images::{emission_map, rerender_hdr};
    use i2sdf_model::material_field::{MaterialConfig, MaterialField};
    use i2sdf_model::{Emitter, ModelConfig, NeuralScene};

    fn emitter(centre: [f64; 3]) -> Emitter {
        Emitter {
            centre,
            extent: [0.2; 3],
            radius: 0.2,
            points: 5,
            sphere: None,
            bounds: None,
            panel: None,
        }
    }

    #[test]
    fn scaled_psnr_removes_a_per_channel_scale() {
        let gt: Vec<f32> = (0..30).map(|i| 0.1 + 0.02 * i as f32).collect();
        // The prediction is half the GT in red, twice in green, exact in blue.
        let pred: Vec<Vec3> = gt.chunks(3).map(|g| Vec3::new(0.5 * g[0], 2.0 * g[1], g[2])).collect();
        let mut mask = vec![true; 10];
        mask[3] = false;
        let mut acc = MaterialAccumulator::default();
        acc.add_albedo(&pred, &gt, &mask);
        let m = acc.finish();
        assert_eq!(m.pixels, Some(9));
        let s = m.albedo_scale.unwrap();
        assert!(
            (s[0] - 2.0).abs() < 1e-5 && (s[1] - 0.5).abs() < 1e-5 && (s[2] - 1.0).abs() < 1e-6,
            "{s:?}"
        );
        assert!(m.albedo_psnr_scaled.unwrap() > 90.0, "{m:?}");
        // Unscaled: the plain PSNR over the masked pixels.
        let mut se = 0.0;
        for (i, p) in pred.iter().enumerate().filter(|(i, _)| mask[*i]) {
            for c in 0..3 {
                se += (p[c] as f64 - gt[i * 3 + c] as f64).powi(2);
            }
        }
        let want = -10.0 * (se / 27.0).log10();
        assert!((m.albedo_psnr.unwrap() - want).abs() < 1e-6);
        assert!(m.roughness_l1.is_none());
        // Two views pooled give one scale: the same as one view holding both.
        let mut two = MaterialAccumulator::default();
        two.add_albedo(&pred[..5], &gt[..15], &mask[..5]);
        two.add_albedo(&pred[5..], &gt[15..], &mask[5..]);
        assert_eq!(two.finish().pixels, m.pixels);
        assert!((two.finish().albedo_psnr.unwrap() - m.albedo_psnr.unwrap()).abs() < 1e-9);
        // Nothing compared: nulls.
        assert_eq!(MaterialAccumulator::default().finish(), MaterialMetrics::default());
    }

    #[test]
    fn roughness_l1_and_masks() {
        let depth = [1.0, f32::INFINITY, 2.0, 3.0];
        let pred_emitter = [false, false, true, false];
        assert_eq!(
            material_mask(&depth, None, &pred_emitter, None),
            [true, false, false, true]
        );
        let gt_mask = ImageF32::from_data(2, 2, 1, vec![0.0, 0.0, 0.0, 1.0]);
        assert_eq!(
            material_mask(&depth, Some(&gt_mask), &pred_emitter, None),
            [true, false, true, false]
        );
        // The dataset's material mask drops the pixels it marks non-GGX (0), whatever else.
        let ggx = ImageF32::from_data(2, 2, 1, vec![0.0, 1.0, 1.0, 1.0]);
        assert_eq!(
            material_mask(&depth, None, &pred_emitter, Some(&ggx)),
            [false, false, false, true]
        );
        let mut acc = MaterialAccumulator::default();
        acc.add_roughness(
            &[0.5, 0.1, 0.2, 0.9],
            &[0.3, 9.0, f32::NAN, 0.0],
            1,
            &[true, false, true, true],
            None,
        );
        let m = acc.finish();
        assert!((m.roughness_l1.unwrap() - (0.2 + 0.9) / 2.0).abs() < 1e-6);
        assert_eq!((m.roughness_l1_lobe, m.lobe_fraction), (None, None));
        // With GT Ks: the lobe figure counts only the pixels whose Ks luminance reaches LOBE_KS
        // (here the first: 0.04), the overall figure all of them as before.
        let mut acc = MaterialAccumulator::default();
        let ks = [0.04, 0.04, 0.04, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0, 0.005, 0.005, 0.005];
        acc.add_roughness(
            &[0.5, 0.1, 0.2, 0.9],
            &[0.3, 9.0, f32::NAN, 0.0],
            1,
            &[true, false, true, true],
            Some((&ks, 3)),
        );
        let m = acc.finish();
        assert!((m.roughness_l1.unwrap() - (0.2 + 0.9) / 2.0).abs() < 1e-6);
        assert!((m.roughness_l1_lobe.unwrap() - 0.2).abs() < 1e-6);
        assert!((m.lobe_fraction.unwrap() - 0.5).abs() < 1e-12);
    }

    #[test]
    fn emitters_match_the_nearest_box() {
        let table = EmitterTable::new(
            vec![emitter([0.0, 2.0, 0.0]), emitter([3.0, 1.0, 0.0])],
            &[[4.0, 4.0, 4.0], [1.0, 2.0, 3.0]],
        );
        let gt = vec![
            GtEmitter {
                name: "lamp".into(),
                emission: [2.0, 4.0, 6.0],
                bounds_min: [2.5, 0.5, -0.5],
                bounds_max: [3.5, 0.8, 0.5],
            },
            GtEmitter {
                name: "ceiling".into(),
                emission: [8.0, 8.0, 8.0],
                bounds_min: [-1.0, 2.0, -1.0],
                bounds_max: [1.0, 2.0, 1.0],
            },
        ];
        let m = emitter_metrics(&table, &gt, Some(0.5));
        assert_eq!(m.count, Some(2));
        assert_eq!(m.centres.as_ref().unwrap()[1], [3.0, 1.0, 0.0]);
        let l = m.emission.as_ref().unwrap();
        assert!((l[1][2] - 3.0).abs() < 1e-5);
        let matches = m.matches.unwrap();
        assert_eq!((matches[0].name.as_str(), matches[0].predicted), ("lamp", Some(1)));
        assert!((matches[0].distance.unwrap() - 0.2).abs() < 1e-12);
        let r = matches[0].emission_ratio.unwrap();
        assert!(r.iter().all(|x| (x - 1.0).abs() < 1e-5), "{r:?}");
        assert_eq!((matches[1].predicted, matches[1].distance), (Some(0), Some(0.0)));
        assert!((matches[1].emission_ratio_mean.unwrap() - 1.0).abs() < 1e-5);
        // No GT emitters: null matches; no predicted emitters: matches without a partner.
        assert!(emitter_metrics(&table, &[], None).matches.is_none());
        let none = emitter_metrics(&EmitterTable::new(Vec::new(), &[]), &gt, None);
        assert_eq!(none.count, Some(0));
        let first = &none.matches.unwrap()[0];
        assert!(first.predicted.is_none() && first.distance.is_none() && first.emission_ratio.is_none());
        assert_eq!(
            distance_to_box([0.0, 0.0, 0.0], [1.0, 2.0, -1.0], [2.0, 3.0, 1.0]),
            5f64.sqrt()
        );
    }

    /// A view counts where its exact depth agrees with the point: a training view taken as the
    /// test view sees all its own pixels, and stops seeing them once its depth is 10 % off;
    /// sensor depth gives no figure.
    #[test]
    fn training_views_seeing_counts_the_views_whose_depth_agrees() {
        let dir = tempfile::tempdir().unwrap();
        i2sdf_data::fixture::write_native(dir.path(), &i2sdf_data::fixture::FixtureOptions::default());
        let mut dataset = i2sdf_data::load(dir.path()).unwrap();
        dataset.depth_exact = true;
        let first = dataset.frames.iter().position(|f| f.split == Split::Train).unwrap();
        let mut probe = dataset.frames[first].clone();
        probe.split = Split::Test;
        let before = training_views_seeing(&dataset, &probe).unwrap();
        let depth = probe.depth.clone().unwrap();
        assert!(depth.data.iter().filter(|z| **z > 0.0).count() > 100);
        for d in dataset.frames[first].depth.as_mut().unwrap().data.iter_mut() {
            *d *= 1.1;
        }
        let after = training_views_seeing(&dataset, &probe).unwrap();
        for (i, z) in depth.data.iter().enumerate() {
            if *z > 0.0 {
                assert!(before[i] >= 1, "pixel {i}: its own view must see it");
                assert_eq!(after[i] + 1, before[i], "pixel {i}");
            } else {
                assert_eq!(before[i], 0);
            }
        }
        dataset.depth_exact = false;
        assert!(training_views_seeing(&dataset, &probe).is_none());
    }

    /// End to end on the fixture dataset with an untrained tiny scene (an inverted sphere that
    /// encloses the cameras): every figure is computed and finite, and the emission map is L[k]
    /// exactly where the re-render sees an emitter.
    #[test]
    fn metrics_on_a_tiny_scene() {
        let dir = tempfile::tempdir().unwrap();
        i2sdf_data::fixture::write_native(dir.path(), &i2sdf_data::fixture::FixtureOptions::default());
        let mut dataset = i2sdf_data::load(dir.path()).unwrap();
        for f in dataset.frames.iter_mut() {
            let (w, h) = (f.camera.width, f.camera.height);
            f.albedo = Some(ImageF32::from_data(w, h, 3, vec![0.5; w * h * 3]));
            f.roughness = Some(ImageF32::from_data(w, h, 1, vec![0.5; w * h]));
            // A lobe on the left half only: the lobe figure counts half the pixels.
            let ks: Vec<f32> = (0..w * h)
                .flat_map(|i| [if i % w < w / 2 { 0.04 } else { 0.0 }; 3])
                .collect();
            f.specular = Some(ImageF32::from_data(w, h, 3, ks));
        }
        let config = ModelConfig {
            hash_levels: 4,
            hash_log2_table: 12,
            hash_finest_resolution: 64,
            ..Default::default()
        };
        let scene = NeuralScene::new(&config, dataset.normalization, 1);
        let material = MaterialConfig {
            hash_levels: 2,
            hash_log2_table: 10,
            hash_finest_resolution: 32,
            ..Default::default()
        };
        let centre = DVec3::from_array(dataset.normalization.center);
        let fields = IntrinsicFields {
            material: MaterialField::new(&material, scene.feature_dim(), 3),
            emitters: EmitterTable::new(vec![emitter((centre + DVec3::Y).to_array())], &[[3.0, 2.0, 1.0]]),
            radiometry: Radiometry::default(),
        };
        let options = IntrinsicOptions {
            spp: 2,
            ..Default::default()
        };
        // Every surface point F_e-positive: the emitter's sphere decides; rays sphere traced.
        let frozen = FrozenScene::labelled(&scene, &fields.emitters, fields.radiometry, -1.0, None, None);
        let (rerender, material, emitters) = intrinsic_metrics(&frozen, &fields, &dataset, &options).unwrap();
        assert!(
            rerender.psnr.unwrap().is_finite() && rerender.ssim.unwrap().is_finite(),
            "{rerender:?}"
        );
        assert!(material.albedo_psnr.unwrap().is_finite(), "{material:?}");
        assert!(material.albedo_psnr_scaled.unwrap() >= material.albedo_psnr.unwrap() - 1e-9);
        assert!(material.roughness_l1.unwrap().is_finite());
        assert!(material.roughness_l1_lobe.unwrap().is_finite(), "{material:?}");
        let lobe = material.lobe_fraction.unwrap();
        assert!(lobe > 0.0 && lobe < 1.0, "{material:?}");
        assert_eq!(emitters.count, Some(1));
        let f = dataset.split(Split::Test).next().unwrap();
        let v = rerender_view(&frozen, &fields.material, &f.camera, 1, 0, 0, &|| {});
        let e = emission_map(&v, &f.camera, &fields.emitters, frozen.index_margin);
        for (i, seen) in v.emitter_mask.iter().enumerate() {
            let want = if *seen { [3.0, 2.0, 1.0] } else { [0.0; 3] };
            let got = &e.data[i * 3..i * 3 + 3];
            assert!(
                got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-5),
                "{got:?} vs {want:?}"
            );
        }
        assert_eq!(rerender_hdr(&v).channels, 3);
    }
}
