//! Benchmark: cost of one LATIN iteration against one monolithic Newmark sweep on the same mesh,
//! factorisation against solve time, and the memory of the stored interface fields.
//!
//! cargo run --release -p glissade-solver --example iteration_cost -- scenes/three-blocks-small.toml [ITERATIONS]
//!
//! The monolithic reference handles perfect interfaces only, so it runs on the same mesh with the
//! contact interfaces glued (its cost does not depend on the interface law).
//!
//! Each solve also prints the bytes it allocated: run with N and 2N iterations, the difference
//! over N is what an iteration allocates (docs/design.md, "Issue 26: before and after").

use std::alloc::{GlobalAlloc, Layout, System};
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

fn run<const D: usize>(scene: &Scene, iterations: usize) {
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
        model.settings.tolerance = 1e-30; // run exactly `iterations` iterations per stage
        let t = Instant::now();
        let mut solver = LatinSolver::serial(&model).expect("factorisation");
        let setup = t.elapsed().as_secs_f64();
        let before = allocated();
        let r = solver.solve(None, &SolveOptions::default()).expect("solve");
        let after = allocated();
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
    println!("{path}: {iterations} iterations per stage");
    match scene.dimension {
        1 => run::<1>(&scene, iterations),
        2 => run::<2>(&scene, iterations),
        _ => run::<3>(&scene, iterations),
    }
}
