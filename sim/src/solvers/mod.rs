//! The solvers that advance a block's [`State`] by one substep, behind one interface
//! ([`Integrator`]), one folder each:
//! * [`explicit`]: Warp's semi-implicit Euler ([`Solver::SemiImplicitEuler`]): one force evaluation
//!   per substep.
//! * [`block_descent`]: implicit Euler solved by Vertex Block Descent ([`Solver::BlockDescent`]).
//! * [`global_descent`]: block descent's implicit Euler step with a global step through a
//!   prefactored banded system before each sweep ([`Solver::GlobalDescent`]), for stiff film at
//!   large substeps.
//!
//! The scene's `integrator.solver` picks one for the whole batch; each block holds it as an
//! [`AnySolver`] with the solver's own buffers and settings, and dispatches once per substep. A
//! solver reads the shared [`Model`], the batch's [`StepConstants`] and what each lane's episode
//! prescribes ([`LaneSetup`]), is given the substep's times and tool poses ([`Substep`]), and
//! updates the [`State`] in place, including the attachment springs' forces for the seal model
//! (the block runs the seal and health checks after it). Force laws come from [`crate::forces`];
//! the solvers never depend on each other, except that global descent drives block descent's
//! sweeps (through [`block_descent::GlobalStep`]).
//!
//! Every solver keeps the lane rules of the batch: a lane's arithmetic never depends on another
//! lane's, frozen lanes are kept bit for bit by per-lane selects, and lane-dependent shortcuts
//! (skipping contacts when every lane is far away) only skip work whose lanes would be left
//! unchanged: contact forces are applied by a per-lane select, never by adding a zero.
//!
//! Adding a solver: a folder with a type implementing [`Integrator`], a variant of [`Solver`]
//! (its name in the scene TOML) and of [`AnySolver`] (with its arm in each `match` below).

pub(crate) mod across_elements;
pub(crate) mod block_descent;
pub(crate) mod explicit;
pub(crate) mod global_descent;
#[cfg(test)]
mod tests;

use crate::config::Solver;
use crate::constants::StepConstants;
use crate::math::{Lanes, Real, V3};
use crate::model::Model;
use crate::state::{LaneSetup, State, ToolLanes};

use block_descent::BlockDescent;
use explicit::SemiImplicitEuler;
use global_descent::GlobalDescent;

/// What a solver is given for one substep besides the state it advances.
pub(crate) struct Substep<'a, const W: usize> {
    pub(crate) model: &'a Model,
    pub(crate) k: &'a StepConstants,
    pub(crate) setup: &'a LaneSetup<W>,
    /// Each lane's time at the end of the substep (s).
    pub(crate) t1: [f64; W],
    /// The tool of each lane at the start of the substep.
    pub(crate) tool: ToolLanes<W>,
    /// Whether the solver may split the block's work over two threads: a single-environment
    /// batch has one block, and the other cores would idle.
    pub(crate) parallel: bool,
    /// The widest instruction set the substep may use (see `substep_entry`).
    pub(crate) simd: Simd,
}

/// `new` in the active lanes of a block (`active` 1), `old` in the frozen ones (0). A function, not
/// a closure in each substep: a closure is compiled on its own, without the substep's instruction
/// set, and at 16 lanes LLVM stops inlining it.
#[inline(always)]
pub(crate) fn keep<const W: usize>(
    active: Lanes<W>,
    new: V3<Lanes<W>>,
    old: V3<Lanes<W>>,
) -> V3<Lanes<W>> {
    V3::select_lt(Lanes::splat(0.5), active, new, old)
}

/// Lanes of a block in batches where the CPU has AVX-512: one 16-lane register per value.
pub(crate) const AVX512_LANES: usize = 16;

/// A solver: maps the state of a block's lanes to the next substep, in place.
pub(crate) trait Integrator<const W: usize> {
    /// The solver for batches of `model`, with its buffers sized for it.
    fn new(model: &Model) -> Self
    where
        Self: Sized;

    /// Advances the active lanes of `state` by one substep; frozen lanes stay bit for bit as they
    /// are. `state.clock` is the substep's start (the caller advances it). Writes
    /// `state.spring_force`.
    fn substep(&mut self, step: &Substep<'_, W>, state: &mut State<W>);

    /// Bytes held by the solver's buffers.
    fn bytes(&self) -> usize;
}

/// The solver of a block, as the scene's `integrator.solver` chose it.
pub(crate) enum AnySolver<const W: usize> {
    SemiImplicitEuler(SemiImplicitEuler<W>),
    BlockDescent(BlockDescent<W>),
    GlobalDescent(GlobalDescent<W>),
}

impl<const W: usize> Integrator<W> for AnySolver<W> {
    fn new(model: &Model) -> Self {
        match model.config.integrator.solver {
            Solver::SemiImplicitEuler => {
                AnySolver::SemiImplicitEuler(SemiImplicitEuler::new(model))
            }
            Solver::BlockDescent => AnySolver::BlockDescent(BlockDescent::new(model)),
            Solver::GlobalDescent => AnySolver::GlobalDescent(GlobalDescent::new(model)),
        }
    }

    fn substep(&mut self, step: &Substep<'_, W>, state: &mut State<W>) {
        match self {
            AnySolver::SemiImplicitEuler(s) => s.substep_entry(step, state),
            AnySolver::BlockDescent(s) => s.substep_entry(step, state),
            AnySolver::GlobalDescent(s) => s.substep_entry(step, state),
        }
    }

    fn bytes(&self) -> usize {
        match self {
            AnySolver::SemiImplicitEuler(s) => s.bytes(),
            AnySolver::BlockDescent(s) => s.bytes(),
            AnySolver::GlobalDescent(s) => s.bytes(),
        }
    }
}

/// The instruction sets the solvers' substeps are compiled for, in order: each substep is the
/// same IEEE arithmetic on every one (no fused multiply-add, see below), only wider.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Simd {
    /// The target's baseline (SSE2 on x86-64).
    Baseline,
    /// AVX2: 8 f32 lanes in a register.
    Avx2,
    /// AVX-512 (foundation): 16 f32 lanes in a register.
    Avx512,
}

impl Simd {
    /// The widest instruction set this CPU has.
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Simd::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Simd::Avx2;
            }
        }
        Simd::Baseline
    }
}

/// Gives a solver `substep_entry`: its substep compiled for the widest instruction set the CPU
/// has, up to `step.simd`. Blocks of [`AVX512_LANES`] lanes, which only CPUs with AVX-512 get,
/// run the AVX-512 copy alone; narrower blocks the AVX2 copy, else the baseline. AVX-512 implies
/// FMA in `target_feature`, but LLVM only fuses a multiply and an add that carry a contraction
/// flag, which Rust never emits: the copies differ in register width, not in results
/// (`solvers/tests.rs` compares their bits). `if const` keeps the copies a width never runs out of
/// the build. Each solver's substep is a function of its own, never inlined into the block's
/// loop: with all three inlined into one function, LLVM takes most of an hour to optimise the
/// crate (its loop passes scale with the function's size).
macro_rules! substep_entry {
    ($solver:ident) => {
        impl<const W: usize> $solver<W> {
            #[inline(never)]
            fn substep_entry(&mut self, step: &Substep<'_, W>, state: &mut State<W>) {
                #[cfg(target_arch = "x86_64")]
                {
                    if const { W == AVX512_LANES } {
                        assert!(
                            step.simd == Simd::Avx512
                                && std::arch::is_x86_feature_detected!("avx512f"),
                            "{AVX512_LANES}-lane blocks are built only where the CPU has AVX-512"
                        );
                        // SAFETY: the CPU supports AVX-512F, checked just above.
                        unsafe { self.substep_avx512(step, state) };
                        return;
                    }
                    if step.simd >= Simd::Avx2 && std::arch::is_x86_feature_detected!("avx2") {
                        // SAFETY: the CPU supports AVX2, checked just above.
                        unsafe { self.substep_avx2(step, state) };
                        return;
                    }
                }
                self.substep(step, state);
            }

            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2")]
            unsafe fn substep_avx2(&mut self, step: &Substep<'_, W>, state: &mut State<W>) {
                self.substep(step, state);
            }

            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx512f")]
            unsafe fn substep_avx512(&mut self, step: &Substep<'_, W>, state: &mut State<W>) {
                self.substep(step, state);
            }
        }
    };
}
substep_entry!(SemiImplicitEuler);
substep_entry!(BlockDescent);
substep_entry!(GlobalDescent);
