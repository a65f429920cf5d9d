//! How a dataset's LDR pixels relate to linear radiance: the transfer they were encoded with and
//! the exposure relating them to the HDR images. Parsed when the dataset is loaded (native
//! `ldr: {transfer, exposure}`, and the same key in a paper-format dataset's optional
//! `radiometry.json`; otherwise sRGB without a declared exposure, as COLMAP's format always is)
//! and read back from stage 2's checkpoint metadata.

use crate::imageio::{self, linear_to_srgb, srgb_to_linear, ImageF32};

/// How display-referred values map to linear radiance in the units of the input images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transfer {
    /// LDR = sRGB OETF(linear) (the default of LDR datasets).
    Srgb,
    /// The values are linear already.
    Linear,
}

impl Transfer {
    /// `"srgb"` or `"linear"`, case-insensitive.
    pub fn from_name(name: &str) -> Option<Transfer> {
        match name.to_ascii_lowercase().as_str() {
            "srgb" => Some(Transfer::Srgb),
            "linear" => Some(Transfer::Linear),
            _ => None,
        }
    }

    /// The name datasets, checkpoints and summaries spell it with: `"srgb"` or `"linear"`.
    pub fn name(self) -> &'static str {
        match self {
            Transfer::Srgb => "srgb",
            Transfer::Linear => "linear",
        }
    }
}

/// The dataset's radiometry: its transfer, and the exposure its LDR images were made with
/// (LDR = transfer(exposure · HDR), so linear image units = exposure × physical radiance).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Radiometry {
    pub transfer: Transfer,
    pub exposure: Option<f64>,
}

impl Default for Radiometry {
    fn default() -> Self {
        Radiometry {
            transfer: Transfer::Srgb,
            exposure: None,
        }
    }
}

impl Radiometry {
    /// Display-referred value (an LDR pixel, F_c's output) → linear radiance in image units.
    #[inline]
    pub fn linearize(&self, v: f32) -> f32 {
        match self.transfer {
            Transfer::Srgb => srgb_to_linear(v),
            Transfer::Linear => v,
        }
    }

    /// Linear radiance → display value for PNG outputs: the dataset's own tone mapping (clamp to
    /// [0, 1], then the transfer's OETF), so a re-rendered image compares directly with the
    /// dataset's photographs.
    #[inline]
    pub fn encode(&self, linear: f32) -> f32 {
        match self.transfer {
            Transfer::Srgb => linear_to_srgb(linear),
            Transfer::Linear => linear.clamp(0.0, 1.0),
        }
    }

    /// [`Radiometry::encode`] of every value of a linear image: the dataset's tone mapping of a
    /// whole image ([`imageio::tone_map_srgb`] for the sRGB transfer), comparable with its LDR
    /// images.
    pub fn encode_image(&self, linear: &ImageF32) -> ImageF32 {
        match self.transfer {
            Transfer::Srgb => imageio::tone_map_srgb(linear, 1.0),
            Transfer::Linear => {
                let mut out = linear.clone();
                out.data.iter_mut().for_each(|x| *x = x.clamp(0.0, 1.0));
                out
            }
        }
    }

    /// `"srgb"` or `"linear"` (case-insensitive); exposure, when given, must be positive.
    pub fn from_name(transfer: &str, exposure: Option<f64>) -> Result<Self, String> {
        let transfer = Transfer::from_name(transfer).ok_or_else(|| {
            format!(
                "transfer = {:?}: must be \"srgb\" or \"linear\"",
                transfer.to_ascii_lowercase()
            )
        })?;
        if let Some(x) = exposure {
            if !(x.is_finite() && x > 0.0) {
                return Err(format!("exposure = {x}: must be a finite positive number"));
            }
        }
        Ok(Radiometry { transfer, exposure })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radiometry() {
        let r = Radiometry::from_name("sRGB", Some(2.0)).unwrap();
        assert_eq!(r.transfer, Transfer::Srgb);
        assert!((r.linearize(r.encode(0.2)) - 0.2).abs() < 1e-5);
        let l = Radiometry::from_name("linear", None).unwrap();
        assert_eq!((l.linearize(0.3), l.encode(1.7)), (0.3, 1.0));
        assert!(Radiometry::default().encode(3.0) > 0.9999);
        assert!(Radiometry::from_name("gamma", None).unwrap_err().contains("srgb"));
        assert!(Radiometry::from_name("srgb", Some(-1.0)).is_err());
    }

    #[test]
    fn transfer_names_round_trip() {
        for t in [Transfer::Srgb, Transfer::Linear] {
            assert_eq!(Transfer::from_name(t.name()), Some(t));
        }
        assert_eq!(Transfer::from_name("LINEAR"), Some(Transfer::Linear));
        assert_eq!(Transfer::from_name("gamma"), None);
    }
}
