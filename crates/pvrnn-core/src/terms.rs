//! The free energy's value and its terms: what an evaluation reports, whichever backend
//! computed it.

use serde::{Deserialize, Serialize};

use crate::config::{Modality, ModuleId};

/// Accuracy (prediction error) terms per modality, each already divided by the observed
/// dimensions and summed over sequences and steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AccuracyTerms {
    pub exteroceptive: f64,
    pub proprioceptive: f64,
}

/// Complexity (KL) terms per module, each divided by the module's z and summed over
/// sequences and steps, *before* multiplying by W.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ComplexityTerms {
    pub executive: f64,
    pub associative: f64,
    pub exteroceptive: f64,
    pub proprioceptive: f64,
}

/// F = sum of accuracy terms + W * sum of complexity terms.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FreeEnergy {
    pub total: f64,
    pub accuracy: AccuracyTerms,
    pub complexity: ComplexityTerms,
}

impl FreeEnergy {
    /// Builds the report from per-modality and per-module sums.
    pub fn from_terms(accuracy: [f64; 2], complexity: [f64; 4], kl_weight: f64) -> Self {
        Self {
            total: accuracy.iter().sum::<f64>() + kl_weight * complexity.iter().sum::<f64>(),
            accuracy: AccuracyTerms {
                exteroceptive: accuracy[Modality::Exteroceptive.index()],
                proprioceptive: accuracy[Modality::Proprioceptive.index()],
            },
            complexity: ComplexityTerms {
                executive: complexity[ModuleId::Executive.index()],
                associative: complexity[ModuleId::Associative.index()],
                exteroceptive: complexity[ModuleId::Exteroceptive.index()],
                proprioceptive: complexity[ModuleId::Proprioceptive.index()],
            },
        }
    }

    pub fn complexity_of(&self, id: ModuleId) -> f64 {
        match id {
            ModuleId::Executive => self.complexity.executive,
            ModuleId::Associative => self.complexity.associative,
            ModuleId::Exteroceptive => self.complexity.exteroceptive,
            ModuleId::Proprioceptive => self.complexity.proprioceptive,
        }
    }
}
