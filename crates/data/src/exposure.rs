//! The exposure measured from the images, not assumed: where a dataset has both LDR and HDR
//! images of its views, LDR = transfer(exposure · HDR) fixes the exposure as the ratio of the
//! linearized LDR value to the HDR value, taken robustly (the median over unsaturated,
//! non-emitter channels bright enough to be above 8-bit quantization). A dataset whose exposure is
//! declared under a key i2sdf does not read, or not at all (the paper's release format), would
//! otherwise be fitted at exposure 1 and its materials come out off by that factor, silently.
//!
//! The spread of the ratios (their median relative deviation) checks the transfer too: under the
//! right transfer the ratio is the same constant at every brightness, under the wrong one it drifts.

use crate::dataset::{Dataset, Split};
use crate::imageio::srgb_to_linear;
use crate::radiometry::Transfer;

/// LDR values used: above quantization and noise, below saturation (and the sRGB knee's clip).
const LDR_RANGE: (f32, f32) = (0.05, 0.9);
/// Channel samples used at most (a stride over the views keeps the estimate a few milliseconds).
const MAX_SAMPLES: usize = 1 << 20;
/// A declared exposure further than this from the measured one (relative) is said.
pub const TOLERANCE: f64 = 0.05;

/// What the images say of their radiometry.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ExposureEstimate {
    /// Median of linearize(LDR) / HDR under the dataset's transfer.
    pub exposure: f64,
    /// Median relative deviation of the ratios from it under the dataset's transfer.
    pub spread: f64,
    /// The same under the other transfer (`srgb` ↔ `linear`): much tighter means the dataset's
    /// transfer is likely wrong.
    pub other_spread: f64,
    /// Channel samples the estimate rests on.
    pub samples: usize,
}

/// The median and the median relative deviation of `ratios` (reordered).
pub(crate) fn median_and_spread(ratios: &mut [f64]) -> (f64, f64) {
    let mid = ratios.len() / 2;
    let median = *ratios.select_nth_unstable_by(mid, f64::total_cmp).1;
    let mut dev: Vec<f64> = ratios.iter().map(|r| (r / median - 1.0).abs()).collect();
    let spread = *dev.select_nth_unstable_by(mid, f64::total_cmp).1;
    (median, spread)
}

/// The exposure of the training views' LDR images relative to their HDR images; `None` when the
/// dataset has no view with both, or too few usable channels (under 1000).
pub fn estimate_exposure(dataset: &Dataset) -> Option<ExposureEstimate> {
    let frames: Vec<_> = dataset.split(Split::Train).filter(|f| f.hdr.is_some()).collect();
    let channels: usize = frames.iter().map(|f| f.rgb.data.len()).sum();
    if channels == 0 {
        return None;
    }
    let stride = channels.div_ceil(MAX_SAMPLES).max(1);
    let srgb = dataset.radiometry.transfer == Transfer::Srgb;
    let (mut own, mut other) = (Vec::new(), Vec::new());
    for f in frames {
        let hdr = f.hdr.as_ref().expect("filtered");
        if hdr.channels != f.rgb.channels {
            continue;
        }
        let mask = f.emitter_mask.as_ref();
        for i in (0..f.rgb.data.len()).step_by(stride) {
            let (v, h) = (f.rgb.data[i], hdr.data[i]);
            let pixel = i / f.rgb.channels;
            let emitter = mask.is_some_and(|m| m.data[pixel * m.channels] > 0.5);
            if emitter || !(LDR_RANGE.0..=LDR_RANGE.1).contains(&v) || !(h > 1e-6 && h.is_finite()) {
                continue;
            }
            let (s, l) = (srgb_to_linear(v) as f64 / h as f64, v as f64 / h as f64);
            let (mine, theirs) = if srgb { (s, l) } else { (l, s) };
            own.push(mine);
            other.push(theirs);
        }
    }
    if own.len() < 1000 {
        return None;
    }
    let (exposure, spread) = median_and_spread(&mut own);
    let (_, other_spread) = median_and_spread(&mut other);
    Some(ExposureEstimate {
        exposure,
        spread,
        other_spread,
        samples: own.len(),
    })
}

impl ExposureEstimate {
    /// Whether a declared exposure is further than [`TOLERANCE`] from the measured one.
    pub fn disagrees_with(&self, declared: f64) -> bool {
        (self.exposure / declared - 1.0).abs() > TOLERANCE
    }

    /// What a user should hear about `dataset`'s declared radiometry against this estimate, if
    /// anything: a declared exposure off by more than [`TOLERANCE`], none declared where the
    /// images say it is not 1, or a transfer under which the ratio drifts while the other's holds.
    pub fn warnings(&self, dataset: &Dataset) -> Vec<String> {
        let mut out = Vec::new();
        match dataset.radiometry.exposure {
            Some(d) if self.disagrees_with(d) => out.push(format!(
                "ldr.exposure = {d} is declared, but the LDR and HDR images say {:.4} (median of {} channels, spread {:.1} %): check the key",
                self.exposure,
                self.samples,
                100.0 * self.spread
            )),
            None if self.disagrees_with(1.0) => out.push(format!(
                "no exposure is declared (ldr.exposure), and the LDR and HDR images say {:.4} (median of {} channels, spread {:.1} %): stage 2 uses the measured value",
                self.exposure,
                self.samples,
                100.0 * self.spread
            )),
            _ => {}
        }
        if self.other_spread < 0.5 * self.spread && self.spread > 0.05 {
            let other = match dataset.radiometry.transfer {
                Transfer::Linear => "srgb",
                Transfer::Srgb => "linear",
            };
            out.push(format!(
                "ldr.transfer = {}: the LDR/HDR ratio varies by {:.1} % under it but only {:.1} % under {other}: is the transfer {other}?",
                dataset.radiometry.transfer.name(),
                100.0 * self.spread,
                100.0 * self.other_spread
            ));
        }
        out
    }
}

/// The exposure stage 2 uses: the declared one, else the measured one, else 1 (`None`).
pub fn exposure_in_use(dataset: &Dataset) -> Option<f64> {
    dataset
        .radiometry
        .exposure
        .or_else(|| estimate_exposure(dataset).map(|e| e.exposure))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixture::{write_native, FixtureOptions};
    use crate::imageio::ImageF32;

    /// The fixture with HDR images made from its LDR ones at a known exposure, under `transfer`.
    fn with_hdr(exposure: f32, transfer: Transfer) -> Dataset {
        let dir = tempfile::tempdir().unwrap();
        write_native(dir.path(), &FixtureOptions::default());
        let mut ds = crate::load(dir.path()).unwrap();
        ds.radiometry.transfer = transfer;
        for f in &mut ds.frames {
            let data = f
                .rgb
                .data
                .iter()
                .map(|&v| if transfer == Transfer::Srgb { srgb_to_linear(v) } else { v } / exposure)
                .collect();
            f.hdr = Some(ImageF32::from_data(f.rgb.width, f.rgb.height, f.rgb.channels, data));
        }
        ds
    }

    #[test]
    fn the_exposure_is_measured_and_a_wrong_declaration_is_said() {
        for transfer in [Transfer::Srgb, Transfer::Linear] {
            let mut ds = with_hdr(4.65, transfer);
            let e = estimate_exposure(&ds).unwrap();
            assert!((e.exposure / 4.65 - 1.0).abs() < 1e-3, "{transfer:?}: {e:?}");
            assert!(e.spread < 1e-3, "{e:?}");
            // Undeclared: said, and used.
            ds.radiometry.exposure = None;
            assert!(e.warnings(&ds)[0].contains("no exposure is declared"));
            assert!((exposure_in_use(&ds).unwrap() / 4.65 - 1.0).abs() < 1e-3);
            // Declared right: nothing to say; declared wrong: said, naming both.
            ds.radiometry.exposure = Some(4.7);
            assert!(e.warnings(&ds).is_empty(), "{:?}", e.warnings(&ds));
            ds.radiometry.exposure = Some(1.0);
            let w = e.warnings(&ds);
            assert!(w[0].contains("ldr.exposure = 1") && w[0].contains("4.65"), "{w:?}");
            assert_eq!(exposure_in_use(&ds), Some(1.0), "a declaration is kept");
        }
    }

    #[test]
    fn a_wrong_transfer_shows_in_the_spread() {
        // Made with sRGB, declared linear.
        let mut ds = with_hdr(2.0, Transfer::Srgb);
        ds.radiometry.transfer = Transfer::Linear;
        let e = estimate_exposure(&ds).unwrap();
        assert!(e.other_spread < 1e-3 && e.spread > 0.05, "{e:?}");
        ds.radiometry.exposure = Some(e.exposure);
        let w = e.warnings(&ds);
        assert!(w.iter().any(|w| w.contains("is the transfer srgb?")), "{w:?}");
        // Without HDR images there is nothing to measure.
        for f in &mut ds.frames {
            f.hdr = None;
        }
        assert!(estimate_exposure(&ds).is_none());
    }
}
