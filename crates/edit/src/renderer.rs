//! One edit rendered view after view, as `i2sdf edit` writes it: the spec applied to the
//! recovered scene, its light gains, and each view's image formed as asked ([`Composite`]):
//! the path-traced render as it is, or over stage 1's radiance field by differential rendering or
//! its ratio form (see [`crate::differential`]).

use crate::apply::light_gains;
use crate::differential::{composite_hdr, hdr_ldr_images, Composite};
use crate::recovered::{edit_images, EditSettings, RecoveredScene};
use crate::scene::EditedScene;
use glam::Vec3;
use i2sdf_data::edit_spec::{EditOp, EditSpec};
use i2sdf_data::{Camera, EditAssets, ImageF32};
use i2sdf_model::renderer::RenderSettings;

/// An edit ready to render: the edited scene with its per-light gains and, for a differential
/// composite, what its base needs.
pub struct EditRenderer<'r, 'a> {
    recovered: &'r RecoveredScene<'a>,
    edited: EditedScene,
    gains: Vec<Vec3>,
    composite: Composite,
    /// The unedited scene, when a differential composite needs its render of the same paths: a
    /// spec that only relights has none (the edited render is its own base: the gains differ,
    /// not the paths).
    unedited: Option<EditedScene>,
    /// Stage 1's render settings, for the captured image of a differential composite.
    volume: &'r RenderSettings,
}

impl<'r, 'a> EditRenderer<'r, 'a> {
    /// `spec` (with its loaded `assets`) over `recovered`, composited as `composite`; `volume`:
    /// the run's stage-1 render settings.
    pub fn new(
        recovered: &'r RecoveredScene<'a>,
        spec: &EditSpec,
        assets: &EditAssets,
        composite: Composite,
        volume: &'r RenderSettings,
    ) -> Self {
        let edited = recovered.edited(spec, assets);
        let relight_only = spec.ops.iter().all(|op| matches!(op, EditOp::Relight(_)));
        let unedited = (composite.over_capture() && !relight_only)
            .then(|| recovered.edited(&EditSpec::default(), &Default::default()));
        let gains = light_gains(spec, &edited);
        EditRenderer {
            recovered,
            edited,
            gains,
            composite,
            unedited,
            volume,
        }
    }

    /// Lights of the edited scene (the recovered emitters and any the spec inserts).
    pub fn lights(&self) -> usize {
        self.edited.lights()
    }

    /// Path-traced renders per view: two when the differential's base is the unedited scene's.
    pub fn passes(&self) -> usize {
        if self.unedited.is_some() {
            2
        } else {
            1
        }
    }

    /// View `view` (the samplers' key, with `settings.seed`) of the edit from `camera`: linear HDR
    /// (image units) and LDR in the dataset's tone mapping. `on_row` is called after each
    /// rendered row of each pass.
    pub fn render(
        &self,
        camera: &Camera,
        settings: &EditSettings,
        view: u32,
        on_row: &(dyn Fn() + Sync),
    ) -> (ImageF32, ImageF32) {
        let (recovered, rm) = (self.recovered, &self.recovered.radiometry);
        let render = recovered.render(&self.edited, camera, settings, view, on_row);
        match self.composite {
            Composite::PathTraced => edit_images(&render, &self.gains, rm),
            kind => {
                let base = self
                    .unedited
                    .as_ref()
                    .map(|u| recovered.render(u, camera, settings, view, on_row));
                let captured = recovered.captured(camera, self.volume);
                let unedited = base.as_ref().unwrap_or(&render);
                let d = composite_hdr(kind, &captured, &render, &self.gains, unedited, rm);
                hdr_ldr_images(&d, render.width, render.height, rm)
            }
        }
    }
}
