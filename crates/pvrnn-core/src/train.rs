//! Learning (eq. 17): full-batch RAdam on every weight and every training sequence's
//! adaptive variables.

use crate::Real;
use crate::backend::{Backend, Learner};
use crate::config::ModelConfig;
use crate::config::{ModuleId, PosteriorInit};
use crate::data::Observations;
use crate::error::{Error, Result};
use crate::free_energy::{FreeEnergy, NoiseDraw, check_model_fits_data, free_energy, window_eps};
use crate::noise::NoiseMode;
use crate::optim::{RAdam, RAdamStep};
use crate::params::{Adaptive, Model, Params, Role};

/// A learning run: the model, its optimiser state and how far it got.
///
/// On a backend that keeps weights on its device between iterations ([`Learner`]) the
/// host's copies of those go stale as it learns; the accessors ([`Self::model`],
/// [`Self::state`], ...) bring them back first, so what they return is always current.
#[derive(Debug)]
pub struct Trainer<T: Real> {
    model: Model<T>,
    optimizer: RAdam<T>,
    /// Completed iterations.
    pub iteration: u64,
    pub noise: NoiseMode,
    backend: Box<dyn Backend<T>>,
    /// The backend's learner, made at the first step; `None` on the CPU.
    learner: Option<Box<dyn Learner<T>>>,
    /// Whether the learner updated its resident tensors since the host last copied them.
    host_stale: bool,
    /// The next iteration's eps, drawn while the device ran this one.
    drawn_ahead: Option<DrawnAhead<T>>,
}

/// eps drawn for a future iteration, with what they were drawn for: used only if the
/// iteration, noise mode and sequence lengths still match when it comes.
#[derive(Debug)]
struct DrawnAhead<T> {
    iteration: u64,
    noise: NoiseMode,
    lengths: Vec<usize>,
    eps: WindowEps<T>,
}

/// What drawing an iteration's eps ahead needs, apart from the trainer (so that another
/// thread can draw them while the trainer's device runs).
struct AheadDraw<'a> {
    config: &'a ModelConfig,
    lengths: &'a [usize],
    iteration: u64,
    noise: NoiseMode,
}

impl AheadDraw<'_> {
    fn draw<T: Real>(self) -> DrawnAhead<T> {
        let _phase = crate::profile::phase("noise of the next iteration, while the device runs");
        DrawnAhead {
            iteration: self.iteration,
            noise: self.noise,
            lengths: self.lengths.to_vec(),
            eps: window_eps(
                self.config,
                self.lengths,
                NoiseDraw::training(self.noise, self.iteration),
            ),
        }
    }
}

/// Names of the tensors the optimiser updates, in its order.
pub fn trainable_names<T: Real>(model: &Model<T>) -> Vec<String> {
    let mut names: Vec<String> = model
        .params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(n, _, _)| n)
        .collect();
    names.extend(model.adaptive.named().into_iter().map(|(n, _)| n));
    names
}

fn trainable_sizes<T: Real>(model: &Model<T>) -> Vec<usize> {
    let mut sizes: Vec<usize> = model
        .params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(_, t, _)| t.len())
        .collect();
    sizes.extend(model.adaptive.named().into_iter().map(|(_, t)| t.len()));
    sizes
}

impl<T: Real> Model<T> {
    /// A fresh model for `sequences` training sequences of `steps` steps, the prior rollout
    /// of `posterior_init = "prior"` computed by `backend` ([`crate::defaults`]'
    /// `Model::init`: on the CPU).
    pub fn init_on(
        backend: &dyn Backend<T>,
        config: ModelConfig,
        sequences: usize,
        steps: usize,
        seed: u64,
    ) -> Result<Self> {
        config.validate()?;
        if sequences == 0 || steps == 0 {
            return Err(Error::InvalidArgument(format!(
                "a model needs at least one sequence of at least one step (got {sequences} x {steps})"
            )));
        }
        let params = Params::init(&config, seed);
        let mut adaptive = Adaptive::zeros(&config, sequences, steps);
        if config.posterior_init == PosteriorInit::Prior {
            // The prior rollout does not depend on data, so every sequence starts the same.
            let (a_mu, a_sigma) = backend.load(&params, &config).prior_rollout(steps);
            for id in ModuleId::ALL {
                let i = id.index();
                for s in 0..sequences {
                    adaptive.a_mu[i].sub_mut(&[s]).copy_from_slice(&a_mu[i]);
                    adaptive.a_sigma[i]
                        .sub_mut(&[s])
                        .copy_from_slice(&a_sigma[i]);
                }
            }
        }
        Ok(Self {
            config,
            params,
            adaptive,
        })
    }
}

impl<T: Real> Trainer<T> {
    /// A new run with fresh optimiser moments, computing on `backend`
    /// ([`crate::defaults`]' `Trainer::new`: on the CPU).
    pub fn new_on(backend: Box<dyn Backend<T>>, model: Model<T>, noise: NoiseMode) -> Self {
        let optimizer = RAdam::new(
            model.config.train.optimizer.clone(),
            &trainable_sizes(&model),
        );
        Self {
            model,
            optimizer,
            iteration: 0,
            noise,
            backend,
            learner: None,
            host_stale: false,
            drawn_ahead: None,
        }
    }

    /// Continues a run from saved state, computing on `backend`
    /// ([`crate::defaults`]' `Trainer::resume`: on the CPU).
    pub fn resume_on(
        backend: Box<dyn Backend<T>>,
        model: Model<T>,
        optimizer: RAdam<T>,
        iteration: u64,
        noise: NoiseMode,
    ) -> Result<Self> {
        let sizes = trainable_sizes(&model);
        let fits = optimizer.m.len() == sizes.len()
            && optimizer.v.len() == sizes.len()
            && optimizer
                .m
                .iter()
                .zip(&optimizer.v)
                .zip(&sizes)
                .all(|((m, v), &n)| m.len() == n && v.len() == n);
        if !fits {
            return Err(Error::Mismatch(
                "the optimiser state does not match the model's tensors".into(),
            ));
        }
        Ok(Self {
            model,
            optimizer,
            iteration,
            noise,
            backend,
            learner: None,
            host_stale: false,
            drawn_ahead: None,
        })
    }

    /// Replaces the arithmetic backend.
    pub fn with_backend(mut self, backend: Box<dyn Backend<T>>) -> Self {
        self.sync();
        self.learner = None;
        self.backend = backend;
        self
    }

    /// The arithmetic the trainer runs on (also for scoring its model as it goes).
    pub fn backend(&self) -> &dyn Backend<T> {
        self.backend.as_ref()
    }

    /// The model's configuration (never changed by learning, so never stale).
    pub fn config(&self) -> &ModelConfig {
        &self.model.config
    }

    /// Fails where the learner's device has failed (out of memory, a lost device): the
    /// tensors it keeps, brought to the host, would then mean nothing. A checkpoint checks
    /// this before it is written ([`crate::io::save_checkpoint`]).
    pub fn check_device(&self) -> Result<()> {
        match self.learner.as_ref().and_then(|l| l.failure()) {
            Some(failure) => Err(failure),
            None => Ok(()),
        }
    }

    /// The model as learned so far.
    pub fn model(&mut self) -> &Model<T> {
        self.sync();
        &self.model
    }

    /// The model and the optimiser as learned so far (what a checkpoint holds).
    pub fn state(&mut self) -> (&Model<T>, &RAdam<T>) {
        self.sync();
        (&self.model, &self.optimizer)
    }

    /// The model and the optimiser to change (a new learning rate, say): the learner's
    /// device copies are dropped, so the next step starts from what the caller leaves.
    pub fn state_mut(&mut self) -> (&mut Model<T>, &mut RAdam<T>) {
        self.sync();
        self.learner = None;
        self.drawn_ahead = None;
        (&mut self.model, &mut self.optimizer)
    }

    /// The model, the run ended.
    pub fn into_model(mut self) -> Model<T> {
        self.sync();
        self.model
    }

    /// Whether the backend keeps weights on its device between iterations, and which
    /// (names, in [`trainable_names`]' order); empty before the first step or on the CPU.
    pub fn resident_tensors(&self) -> Vec<String> {
        let names = trainable_names(&self.model);
        self.learner
            .as_ref()
            .map(|l| l.resident().iter().map(|&i| names[i].clone()).collect())
            .unwrap_or_default()
    }

    /// How many tensors the optimiser updates ([`trainable_names`]' length).
    pub fn trainable_tensors(&self) -> usize {
        self.optimizer.m.len()
    }

    /// Copies the learner's resident tensors and moments into the host's model and
    /// optimiser, if it updated them since the last copy.
    fn sync(&mut self) {
        let Some(learner) = self.learner.as_ref().filter(|_| self.host_stale) else {
            return;
        };
        let mut values: Vec<&mut [T]> = trainable_slices(&mut self.model);
        for &i in learner.resident() {
            learner.download(
                i,
                values[i],
                &mut self.optimizer.m[i],
                &mut self.optimizer.v[i],
            );
        }
        self.host_stale = false;
    }

    /// One full-batch iteration; returns the free energy at which the gradient was taken.
    pub fn step(&mut self, data: &Observations<T>) -> Result<FreeEnergy> {
        crate::parallel::in_pool(|| self.step_here(data))
    }

    fn step_here(&mut self, data: &Observations<T>) -> Result<FreeEnergy> {
        let eps = self.begin(data)?;
        if eps.is_some() && self.guarded() {
            let mut members = [self];
            let mut stepped = step_ahead(&mut members, &[data], vec![Ok(eps)]);
            return stepped.pop().unwrap_or_else(|| {
                Err(Error::Mismatch(
                    "one learning run stepped, no result".into(),
                ))
            });
        }
        let on_device = match eps {
            Some(eps) => {
                let queued = self.device_iteration(data, &eps)?;
                let next = self.next_draw(data);
                let (report, ahead) = crate::parallel::while_waiting(
                    || crate::deferred::now(queued),
                    move || next.draw(),
                );
                self.drawn_ahead = Some(ahead);
                Some(report?)
            }
            None => None,
        };
        self.finish(data, on_device)
    }

    /// Whether the learner evaluates whole iterations and guards its updates on the device
    /// ([`Learner::guards_updates`]): the next iteration is then queued before this one's
    /// free energy is read back ([`step_ahead`]).
    fn guarded(&self) -> bool {
        self.learner.as_ref().is_some_and(|l| l.guards_updates())
    }

    /// After a learning evaluation diverged on a learner that guards its updates: its
    /// tensors as they were before (the device skipped its update; the next evaluation,
    /// queued behind it, changes no tensor) back on the host, the learner dropped (the next
    /// step makes a new one), the optimiser's step count back to match.
    fn spend_learner(&mut self) {
        self.sync();
        self.learner = None;
        self.drawn_ahead = None;
        self.optimizer.step -= 1;
    }

    /// The draw of the iteration after this one.
    fn next_draw<'a>(&'a self, data: &'a Observations<T>) -> AheadDraw<'a> {
        AheadDraw {
            config: &self.model.config,
            lengths: data.lengths(),
            iteration: self.iteration + 1,
            noise: self.noise,
        }
    }

    /// This iteration's eps: drawn ahead while the device ran the last one, if they were
    /// drawn for it, or drawn now.
    fn this_iterations_eps(&mut self, data: &Observations<T>) -> WindowEps<T> {
        match self.drawn_ahead.take() {
            Some(ahead)
                if ahead.iteration == self.iteration
                    && ahead.noise == self.noise
                    && ahead.lengths == data.lengths() =>
            {
                ahead.eps
            }
            _ => {
                let draw = NoiseDraw::training(self.noise, self.iteration);
                window_eps(&self.model.config, data.lengths(), draw)
            }
        }
    }

    /// Makes the learner at the first step; where it evaluates whole iterations on its
    /// device, checks the data and returns this iteration's eps for it (`None`: the host
    /// evaluates, in [`Self::finish`]).
    fn begin(&mut self, data: &Observations<T>) -> Result<Option<WindowEps<T>>> {
        if self.learner.is_none() {
            self.learner = self.backend.learner(&self.model, &self.optimizer);
        }
        let Some(learner) = &self.learner else {
            return Ok(None);
        };
        let whole = learner.runs_whole_iterations();
        if whole != (learner.resident().len() == self.optimizer.m.len()) {
            return Err(Error::Mismatch(
                "the backend's learner keeps every trainable tensor on its device only if it evaluates iterations there whole".into(),
            ));
        }
        if !whole {
            return Ok(None);
        }
        check_model_fits_data(&self.model, data)?;
        Ok(Some(self.this_iterations_eps(data)))
    }

    /// The learner that evaluates whole iterations on its device.
    fn whole_learner(&self) -> Result<&dyn Learner<T>> {
        self.learner
            .as_deref()
            .ok_or_else(|| Error::Mismatch("a learning run on its device has no learner".into()))
    }

    /// Starts what the learner queued on its device ([`Learner::submit_queued`]).
    fn submit_queued(&self) {
        if let Some(learner) = &self.learner {
            learner.submit_queued();
        }
    }

    /// The iteration evaluated on the learner's device (after [`Self::begin`] gave `eps`),
    /// queued there; awaiting it waits for the device.
    fn device_iteration<'a>(
        &'a self,
        data: &'a Observations<T>,
        eps: &'a [[Vec<T>; 4]],
    ) -> Result<crate::deferred::Deferred<'a, Result<FreeEnergy>>> {
        self.learner
            .as_ref()
            .and_then(|learner| learner.begin_free_energy(data, eps))
            .ok_or_else(|| {
                Error::Mismatch(
                    "the backend's learner did not evaluate the iteration it keeps on its device"
                        .into(),
                )
            })
    }

    /// The rest of an iteration: the evaluation on the host unless the device gave
    /// `on_device`, the finiteness check and the optimiser's step.
    fn finish(
        &mut self,
        data: &Observations<T>,
        on_device: Option<FreeEnergy>,
    ) -> Result<FreeEnergy> {
        let draw = NoiseDraw::training(self.noise, self.iteration);
        let (report, grads) = match on_device {
            Some(report) => (report, None),
            None => {
                let evaluator: &dyn Backend<T> = match &self.learner {
                    Some(learner) => learner.as_ref(),
                    None => self.backend.as_ref(),
                };
                let (report, grads) = free_energy(evaluator, &self.model, data, draw, true)?;
                (report, Some(grads.expect("gradients requested")))
            }
        };
        if !report.total.is_finite() {
            return Err(diverged(&report, self.iteration));
        }
        let mut grad_slices: Vec<&[T]> = Vec::new();
        if let Some(grads) = &grads {
            grad_slices.extend(
                grads
                    .params
                    .named()
                    .into_iter()
                    .filter(|(_, _, role)| *role == Role::Trainable)
                    .map(|(_, t, _)| t.data()),
            );
            grad_slices.extend(grads.adaptive.named().into_iter().map(|(_, t)| t.data()));
        }
        let resident = self.learner.as_ref().map_or(&[][..], |l| l.resident());
        let step = self.optimizer.begin_step();
        if let Some(learner) = &self.learner {
            let _phase = crate::profile::phase("optimiser on the device (queued)");
            learner.update(&step);
            self.host_stale = true;
        }
        for (i, (p, g)) in trainable_slices(&mut self.model)
            .into_iter()
            .zip(grad_slices)
            .enumerate()
        {
            if !resident.contains(&i) {
                self.optimizer.apply(&step, i, p, g);
            }
        }
        self.iteration += 1;
        Ok(report)
    }
}

/// The error of a learning iteration whose free energy is not finite.
fn diverged(report: &FreeEnergy, iteration: u64) -> Error {
    Error::Numerical(format!(
        "the free energy became {} at iteration {iteration}: learning diverged (try a smaller train.optimizer.lr)",
        report.total
    ))
}

/// One iteration of runs whose learners guard their updates ([`Learner::guards_updates`];
/// `eps[i]` from [`Trainer::begin`]), with the next iteration queued before this one is
/// read back, so that the device runs it while the host checks this one and the caller
/// does its bookkeeping: every run's evaluation (queued by the step before when it was for
/// these eps), then every run's update behind it, then every run's next evaluation behind
/// that; then the free energies awaited. A run that diverged had its update skipped on the
/// device, and its learner is spent ([`Trainer::spend_learner`]). The results are those of
/// [`Trainer::finish`]'s order of events, exactly.
fn step_ahead<T: Real>(
    members: &mut [&mut Trainer<T>],
    data: &[&Observations<T>],
    eps: Vec<Result<Option<WindowEps<T>>>>,
) -> Vec<Result<FreeEnergy>> {
    // This iteration's evaluations, queued (or found queued); a run whose evaluation could
    // not be queued gets no update, and its error.
    let (queued, mut errors): (Vec<Option<WindowEps<T>>>, Vec<Option<Error>>) = members
        .iter()
        .zip(data)
        .zip(eps)
        .map(|((m, d), e)| {
            let queue = |e: Option<WindowEps<T>>| {
                let e = e.ok_or_else(|| {
                    Error::Mismatch(
                        "the learner guards its updates but evaluates on the host".into(),
                    )
                })?;
                m.whole_learner()?.queue_free_energy(d, &e)?;
                Ok(e)
            };
            match e.and_then(queue) {
                Ok(e) => (Some(e), None),
                Err(error) => (None, Some(error)),
            }
        })
        .unzip();
    let steps: Vec<Option<RAdamStep>> = members
        .iter_mut()
        .zip(&queued)
        .map(|(m, q)| q.as_ref().map(|_| m.optimizer.begin_step()))
        .collect();
    let (reports, ahead): (Vec<Result<FreeEnergy>>, Vec<Option<DrawnAhead<T>>>) = {
        let members: &[&mut Trainer<T>] = members;
        let claimed: Vec<Result<_>> = members
            .iter()
            .zip(data)
            .zip(&queued)
            .zip(&mut errors)
            .map(|(((m, d), e), error)| match e {
                Some(e) => m.device_iteration(d, e),
                None => Err(error.take().unwrap_or_else(|| {
                    Error::Mismatch("a learning run's evaluation was not queued".into())
                })),
            })
            .collect();
        members.iter().for_each(|m| m.submit_queued());
        for ((m, step), c) in members.iter().zip(&steps).zip(&claimed) {
            if let (Some(step), Ok(_), Ok(learner)) = (step, c, m.whole_learner()) {
                let _phase = crate::profile::phase("optimiser on the device (queued)");
                learner.update(step);
            }
        }
        let ahead: Vec<Option<DrawnAhead<T>>> = members
            .iter()
            .zip(data)
            .zip(&claimed)
            .map(|((m, d), c)| {
                let ahead: DrawnAhead<T> = c.as_ref().ok().map(|_| m.next_draw(d).draw())?;
                // An error here comes back, and is reported, when the next step queues
                // its evaluation itself.
                let _ = m
                    .whole_learner()
                    .map(|l| l.queue_free_energy(d, &ahead.eps));
                Some(ahead)
            })
            .collect();
        members.iter().for_each(|m| m.submit_queued());
        let reports = claimed
            .into_iter()
            .map(|c| c.and_then(crate::deferred::now))
            .collect();
        (reports, ahead)
    };
    members
        .iter_mut()
        .zip(reports.into_iter().zip(ahead))
        .zip(steps)
        .map(|((m, (report, ahead)), step)| {
            if step.is_some() {
                m.host_stale = true;
            }
            m.drawn_ahead = ahead;
            match report {
                Ok(report) if report.total.is_finite() => {
                    m.iteration += 1;
                    Ok(report)
                }
                Ok(report) => {
                    m.spend_learner();
                    Err(diverged(&report, m.iteration))
                }
                Err(e) => {
                    if step.is_some() {
                        m.spend_learner();
                    }
                    Err(e)
                }
            }
        })
        .collect()
}

/// An iteration's eps per sequence and module ([`window_eps`]).
type WindowEps<T> = Vec<[Vec<T>; 4]>;

/// One iteration of several learning runs at once (a cohort: networks of one experiment
/// condition with different seeds, `members[i]` learning `data[i]`). Where the runs' learners
/// evaluate whole iterations on one device, every run's iteration is queued there before
/// the host waits for the first, so the device runs them back to back; the others step
/// one after another. Each run's result is exactly that of [`Trainer::step`] alone (the
/// backend suite checks it). Returns each run's free energy or error, in order.
pub fn step_together<T: Real>(
    members: &mut [&mut Trainer<T>],
    data: &[&Observations<T>],
) -> Result<Vec<Result<FreeEnergy>>> {
    if members.len() != data.len() {
        return Err(Error::InvalidArgument(format!(
            "{} learning runs but {} datasets: every run steps on its own",
            members.len(),
            data.len()
        )));
    }
    crate::parallel::in_pool(|| {
        make_learners_together(members)?;
        let mut eps: Vec<Result<Option<WindowEps<T>>>> = members
            .iter_mut()
            .zip(data)
            .map(|(m, d)| m.begin(d))
            .collect();
        if members.iter().all(|m| m.guarded()) {
            return Ok(step_ahead(members, data, eps));
        }
        // Queued on the device, all of them, then awaited in order, while the next
        // iteration's eps of the runs on the device are drawn.
        let (on_device, ahead): (Vec<Option<Result<FreeEnergy>>>, Vec<Option<_>>) = {
            let queued: Vec<Option<Result<_>>> = members
                .iter()
                .zip(data)
                .zip(&eps)
                .map(|((m, d), e)| match e {
                    Ok(Some(e)) => Some(m.device_iteration(d, e)),
                    _ => None,
                })
                .collect();
            let next: Vec<Option<AheadDraw<'_>>> = members
                .iter()
                .zip(data)
                .zip(&queued)
                .map(|((m, d), q)| q.as_ref().map(|_| m.next_draw(d)))
                .collect();
            crate::parallel::while_waiting(
                || {
                    queued
                        .into_iter()
                        .map(|q| q.map(|q| q.and_then(crate::deferred::now)))
                        .collect()
                },
                move || next.into_iter().map(|n| n.map(AheadDraw::draw)).collect(),
            )
        };
        for (member, ahead) in members.iter_mut().zip(ahead) {
            member.drawn_ahead = ahead;
        }
        Ok(members
            .iter_mut()
            .zip(data)
            .zip(eps.iter_mut().zip(on_device))
            .map(|((m, d), (e, device))| {
                std::mem::replace(e, Ok(None))?;
                let report = device.transpose()?;
                m.finish(d, report)
            })
            .collect())
    })
}

/// The learners of the runs that have none yet, made together by the first such run's
/// backend ([`Backend::learners`]: a device may lay a cohort out side by side). The runs of
/// a cohort compute on one backend.
fn make_learners_together<T: Real>(members: &mut [&mut Trainer<T>]) -> Result<()> {
    let missing: Vec<usize> = (0..members.len())
        .filter(|&i| members[i].learner.is_none())
        .collect();
    let Some(&first) = missing.first() else {
        return Ok(());
    };
    let learners = {
        let runs: Vec<(&Model<T>, &RAdam<T>)> = missing
            .iter()
            .map(|&i| (&members[i].model, &members[i].optimizer))
            .collect();
        members[first].backend.learners(&runs)?
    };
    for (i, learner) in missing.into_iter().zip(learners) {
        members[i].learner = learner;
    }
    Ok(())
}

/// The trainable tensors' values, in [`trainable_names`]' order.
fn trainable_slices<T: Real>(model: &mut Model<T>) -> Vec<&mut [T]> {
    let mut slices: Vec<&mut [T]> = Vec::new();
    for (_, t, role) in model.params.named_mut() {
        if role == Role::Trainable {
            slices.push(t.data_mut());
        }
    }
    for (_, t) in model.adaptive.named_mut() {
        slices.push(t.data_mut());
    }
    slices
}
