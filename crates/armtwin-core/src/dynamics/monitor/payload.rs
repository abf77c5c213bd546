//! The payload the monitor models (applied, else the controller's, else the configured one),
//! the payload identified from samples at rest ([`crate::dynamics::payload`]'s identifier), and
//! the mismatch alarm between the two.

use super::{EffortAlarm, Monitor, PayloadSource};
use crate::dynamics::Payload;

/// Rest samples between two payload estimates (an estimate solves a 4×4 eigenproblem).
const PAYLOAD_ESTIMATE_EVERY: u32 = 50;

impl<const N: usize> Monitor<N> {
    /// Adds a program-mode sample at rest to the payload identification; estimates every
    /// [`PAYLOAD_ESTIMATE_EVERY`] of them.
    pub(super) fn identify_at_rest(
        &mut self,
        q: &[f64; N],
        measured_nm: &[f64; N],
        on_alarm: &mut impl FnMut(EffortAlarm),
    ) {
        let arm_nm = self.arm_only.gravity_nm(q);
        let beyond: [f64; N] = std::array::from_fn(|k| measured_nm[k] - arm_nm[k]);
        self.identifier
            .add_static_sample(&self.arm_only, q, &beyond);
        self.rest_since_estimate += 1;
        if self.rest_since_estimate >= PAYLOAD_ESTIMATE_EVERY {
            self.rest_since_estimate = 0;
            let identification = self
                .identifier
                .identify(self.config.payload_reach_m, self.in_use.0.cog_flange_m);
            self.identification = Some(identification);
            self.estimate = identification.estimate();
            self.check_payload(on_alarm);
        }
    }

    /// The payload the model uses: applied, else the controller's, else the configured one.
    pub(super) fn update_payload_in_use(&mut self) {
        let wanted = if let Some(applied) = self.applied {
            (applied, PayloadSource::Applied)
        } else if let Some(controller) = self.controller_payload {
            (controller, PayloadSource::Controller)
        } else if let Some(config) = self.config.payload {
            (config, PayloadSource::Config)
        } else {
            (Payload::NONE, PayloadSource::None)
        };
        if wanted == self.in_use {
            return;
        }
        // A payload the dynamics refuse (a negative mass from a gateway) is modelled as none.
        self.loaded = self
            .arm_only
            .clone()
            .with_payload(wanted.0)
            .unwrap_or_else(|_| self.arm_only.clone());
        self.in_use = wanted;
    }

    fn check_payload(&mut self, on_alarm: &mut impl FnMut(EffortAlarm)) {
        let Some(estimate) = self.estimate else {
            return;
        };
        let modelled_kg = self.in_use.0.mass_kg;
        let tolerance_kg = self.config.payload_tolerance_kg;
        let difference = (estimate.mass_kg - modelled_kg).abs();
        let on = if self.payload_mismatch {
            difference > tolerance_kg
        } else {
            difference > tolerance_kg + 3.0 * estimate.mass_std_kg
        };
        if on != self.payload_mismatch {
            self.payload_mismatch = on;
            on_alarm(EffortAlarm::Payload {
                estimated_kg: estimate.mass_kg,
                std_kg: estimate.mass_std_kg,
                modelled_kg,
                tolerance_kg,
                on,
            });
        }
    }

    /// Applies the latest identified payload to the model; returns it, or `None` when there is
    /// none (or it has no centre of gravity). The alarm is cleared at the next estimate.
    pub(super) fn apply_estimate(&mut self) -> Option<Payload> {
        let estimate = self.estimate?;
        let payload = Payload::point_mass(estimate.mass_kg, estimate.cog_flange_m?);
        self.applied = Some(payload);
        self.update_payload_in_use();
        Some(payload)
    }

    /// Returns to the controller's (or configured) payload.
    pub(super) fn discard_applied(&mut self) {
        self.applied = None;
        self.update_payload_in_use();
    }
}
