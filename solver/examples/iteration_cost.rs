//! Benchmark: cost of one LATIN iteration against one monolithic Newmark sweep on the same mesh,
//! factorisation against solve time, and the memory of the stored interface fields.
//!
//! cargo run --release -p glissade-solver --example iteration_cost -- scenes/three-blocks-small.toml [ITERATIONS]
//!
//! The monolithic reference handles perfect interfaces only, so it runs on the same mesh with the
//! contact interfaces glued (its cost does not depend on the interface law).
//!
//! "one dynamic iteration" is the linear and local stages' time per step of both stages, times the
//! steps (static iterations count one step each). The dynamic stage alone is also timed, from
//! the solver's per-iteration events: wall and CPU time of this thread (Linux's
//! /proc/thread-self/schedstat). On a shared machine the wall time follows the load and a 0.06 s
//! sweep is a noisy yardstick: compare builds in one run, alternating (docs/performance.md, "Why an
//! iteration got slower").
//! Each solve also prints the bytes it allocated: run with N and 2N iterations, the difference
//! over N is what an iteration allocates (the notebook, docs/notebook/2026-11-26.md, "Issue 26: before and after").

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scale, Scene};
use glissade_solver::latin::{LatinSolver, SolveOptions};
use glissade_solver::model::Model;
use glissade_solver::monolithic;

/// The system allocator, counting the bytes and the calls it is asked for.
struct Counting;

static ALLOCATED: AtomicUsize = AtomicUsize::new(0);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATED.fetch_add(layout.size(), Ordering::Relaxed);
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's contract for `alloc`, passed on unchanged
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` above with this layout
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATED.fetch_add(new_size, Ordering::Relaxed);
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's contract for `realloc`, passed on unchanged
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static COUNTING: Counting = Counting;

/// (bytes, calls) allocated so far.
fn allocated() -> (usize, usize) {
    (ALLOCATED.load(Ordering::Relaxed), ALLOCATIONS.load(Ordering::Relaxed))
}

/// CPU time of the calling thread in seconds, where Linux tells it.
fn thread_cpu_seconds() -> Option<f64> {
    use std::io::Read;
    // read into the stack: the allocation count must not see the timing
    let mut buffer = [0u8; 128];
    let n = std::fs::File::open("/proc/thread-self/schedstat").ok()?.read(&mut buffer).ok()?;
    let stat = std::str::from_utf8(&buffer[..n]).ok()?;
    let ns: f64 = stat.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

/// One LATIN iteration's event: dynamic stage or not, wall clock, this thread's CPU time.
type Mark = (bool, Instant, Option<f64>);

/// Marks the end of each LATIN iteration (the solver's `tracing::debug!` "LATIN iteration").
struct IterationMarks(Mutex<Vec<Mark>>);

struct StageField(bool);

impl tracing::field::Visit for StageField {
    fn record_str(&mut self, field: &tracing::field::Field, value: &str) {
        if field.name() == "stage" {
            self.0 = value == "dynamic";
        }
    }
    fn record_debug(&mut self, _: &tracing::field::Field, _: &dyn std::fmt::Debug) {}
}

impl tracing::Subscriber for &'static IterationMarks {
    fn enabled(&self, meta: &tracing::Metadata<'_>) -> bool {
        meta.is_event() && meta.fields().field("iteration").is_some() && meta.fields().field("stage").is_some()
    }
    fn new_span(&self, _: &tracing::span::Attributes<'_>) -> tracing::span::Id {
        tracing::span::Id::from_u64(1)
    }
    fn record(&self, _: &tracing::span::Id, _: &tracing::span::Record<'_>) {}
    fn record_follows_from(&self, _: &tracing::span::Id, _: &tracing::span::Id) {}
    fn event(&self, event: &tracing::Event<'_>) {
        let mut stage = StageField(false);
        event.record(&mut stage);
        let mark = (stage.0, Instant::now(), thread_cpu_seconds());
        self.0.lock().expect("marks").push(mark);
    }
    fn enter(&self, _: &tracing::span::Id) {}
    fn exit(&self, _: &tracing::span::Id) {}
}

/// The dynamic stage's (wall, CPU) seconds per iteration, from its first iteration's end to its
/// last's (the stage's start and the post-processing left out), and the static iterations.
fn dynamic_per_iteration(marks: &[Mark]) -> (Option<(f64, Option<f64>)>, usize) {
    let statics = marks.iter().filter(|m| !m.0).count();
    let dynamic: Vec<&Mark> = marks.iter().filter(|m| m.0).collect();
    let (Some(first), Some(last)) = (dynamic.first(), dynamic.last()) else { return (None, statics) };
    if dynamic.len() < 2 {
        return (None, statics);
    }
    let n = (dynamic.len() - 1) as f64;
    let cpu = first.2.zip(last.2).map(|(a, b)| (b - a) / n);
    (Some(((last.1 - first.1).as_secs_f64() / n, cpu)), statics)
}

fn run<const D: usize>(scene: &Scene, iterations: usize, marks: &IterationMarks) {
    let values = scene.parameter_values(&DesignPoint::new()).expect("parameters");
    let mut glued_scene = scene.clone();
    for itf in &mut glued_scene.interfaces {
        itf.law = glissade_core::scene::LawSpec::Perfect;
    }
    let glued = Model::<D>::build(&glued_scene, &values).expect("model");
    let t = Instant::now();
    let mono = monolithic::solve(&glued).expect("monolithic");
    let mono_total = t.elapsed().as_secs_f64();
    println!(
        "monolithic: {} dofs, factorisation {:.3} s, sweep of {} steps {:.3} s (total {:.3} s)",
        mono.displacement[0].len(),
        mono.factorisation_seconds,
        glued.steps,
        mono.sweep_seconds,
        mono_total
    );
    for scale in [Scale::Single, Scale::Multi] {
        let mut model = Model::<D>::build(scene, &values).expect("model");
        model.settings.scale = scale;
        model.settings.max_iterations = iterations;
        // the dynamic stage runs exactly `iterations` iterations (the static stage to its floor,
        // STATIC_TOLERANCE_FLOOR, or its limit)
        model.settings.tolerance = 1e-30;
        let t = Instant::now();
        let mut solver = LatinSolver::serial(&model).expect("factorisation");
        let setup = t.elapsed().as_secs_f64();
        {
            // room for every mark made, so that keeping them allocates nothing the count sees
            let mut m = marks.0.lock().expect("marks");
            m.clear();
            m.reserve(100_000);
        }
        let before = allocated();
        let r = solver.solve(None, &SolveOptions::default()).expect("solve");
        let after = allocated();
        let (alone, statics) = dynamic_per_iteration(&marks.0.lock().expect("marks"));
        let dynamic_iterations = r.dynamic.iterations as f64;
        let static_iterations = r.static_stage.as_ref().map_or(0, |s| s.iterations) as f64;
        // a static iteration is one step, a dynamic one `steps` steps
        let per_step_units = dynamic_iterations * model.steps as f64 + static_iterations;
        let iteration = (r.timings.linear_stage + r.timings.local_stage) / per_step_units * model.steps as f64;
        let interface_values: usize = r.solution.dynamic.interfaces.iter().map(|f| 2 * f.s.len() * f.len()).sum();
        // s and s^ (F and W each), plus the relaxation copy of s
        let bytes_per_step = (interface_values as f64 * 1.5 * 8.0) / model.steps as f64;
        println!(
            "LATIN {scale:?}: {} substructures, setup (factorisations{}) {:.3} s, one dynamic iteration {:.3} s = {:.2} x monolithic sweep; local stage {:.0} % of an iteration; interface fields {:.1} kB per time step",
            model.substructures.len(),
            if scale == Scale::Multi { " + macro operators" } else { "" },
            setup,
            iteration,
            iteration / mono.sweep_seconds,
            100.0 * r.timings.local_stage / (r.timings.linear_stage + r.timings.local_stage),
            bytes_per_step / 1e3
        );
        if let Some((wall, cpu)) = alone {
            let cpu = cpu.map_or_else(|| "unknown".to_owned(), |c| format!("{c:.4} s"));
            println!(
                "  dynamic stage alone: {wall:.4} s wall, {cpu} CPU per iteration ({statics} static iterations before)"
            );
        }
        println!(
            "  the solve ({} static + {} dynamic iterations) allocated {} bytes in {} calls",
            static_iterations,
            dynamic_iterations,
            after.0 - before.0,
            after.1 - before.1
        );
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args.next().expect("usage: iteration_cost SCENE.toml [ITERATIONS]");
    let iterations: usize = args.next().map_or(5, |s| s.parse().expect("ITERATIONS is a number"));
    let scene = Scene::read(std::path::Path::new(&path)).expect("scene");
    let marks: &'static IterationMarks = Box::leak(Box::new(IterationMarks(Mutex::new(Vec::new()))));
    tracing::subscriber::set_global_default(marks).expect("subscriber");
    println!("{path}: {iterations} dynamic iterations");
    match scene.dimension {
        1 => run::<1>(&scene, iterations, marks),
        2 => run::<2>(&scene, iterations, marks),
        _ => run::<3>(&scene, iterations, marks),
    }
}
