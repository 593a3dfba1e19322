//! One module's distributions and states, row-major over steps ([`ModuleStates`]): the one
//! type every consumer of module states shares.

/// One module's distributions and states, row-major `[steps, width]`: at one step
/// (`steps = 1`, in a [`StepOutput`](super::StepOutput)) or stacked over a whole run (in a [`Run`](super::Run), and in the
/// explorer's traces and worker messages). Widths: z for the four distributions, d for `d`
/// and `prior_d`. The one type every consumer of module states shares.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModuleStates<T> {
    pub mu_p: Vec<T>,
    pub sigma_p: Vec<T>,
    pub mu_q: Vec<T>,
    pub sigma_q: Vec<T>,
    pub d: Vec<T>,
    /// d in the one-step-ahead prior step (x^_{t+1} is the read-out of these).
    pub prior_d: Vec<T>,
}

impl<T: Copy> ModuleStates<T> {
    /// The field names as they appear in files (`<module>.<field>`), in a fixed order.
    pub const FIELDS: [&'static str; 6] = ["mu_p", "sigma_p", "mu_q", "sigma_q", "d", "prior_d"];

    /// The fields in [`Self::FIELDS`] order.
    pub fn fields(&self) -> [&Vec<T>; 6] {
        [
            &self.mu_p,
            &self.sigma_p,
            &self.mu_q,
            &self.sigma_q,
            &self.d,
            &self.prior_d,
        ]
    }

    /// The fields in [`Self::FIELDS`] order, mutable.
    pub fn fields_mut(&mut self) -> [&mut Vec<T>; 6] {
        [
            &mut self.mu_p,
            &mut self.sigma_p,
            &mut self.mu_q,
            &mut self.sigma_q,
            &mut self.d,
            &mut self.prior_d,
        ]
    }

    /// Widths of the fields in [`Self::FIELDS`] order, for a module of these sizes.
    pub fn widths(z: usize, d: usize) -> [usize; 6] {
        [z, z, z, z, d, d]
    }

    /// Appends `other`'s steps.
    pub fn extend(&mut self, other: &Self) {
        for (mine, theirs) in self.fields_mut().into_iter().zip(other.fields()) {
            mine.extend_from_slice(theirs);
        }
    }

    /// Stacks the states of consecutive steps.
    pub fn stack<'a>(steps: impl IntoIterator<Item = &'a Self>) -> Self
    where
        T: 'a,
    {
        let mut all = Self {
            mu_p: Vec::new(),
            sigma_p: Vec::new(),
            mu_q: Vec::new(),
            sigma_q: Vec::new(),
            d: Vec::new(),
            prior_d: Vec::new(),
        };
        for s in steps {
            all.extend(s);
        }
        all
    }
}
