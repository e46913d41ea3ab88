use glissade_worker::comm::Serial;
use glissade_worker::latin::field::InterfaceSolution;
use glissade_worker::run::{PointSolver, SolveRequest};
use glissade_worker::scene::Scene;
fn map(sol: &InterfaceSolution, f: &dyn Fn(&mut glissade_worker::latin::field::InterfaceField)) -> InterfaceSolution {
    let mut s = sol.clone();
    if let Some(st) = s.static_stage.as_mut() {
        st.interfaces.iter_mut().for_each(|i| f(i));
    }
    s.dynamic.interfaces.iter_mut().for_each(|i| f(i));
    s
}
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mut scene = Scene::parse(&std::fs::read_to_string(&a[1]).unwrap()).unwrap();
    if let Some(k) = a.get(6) {
        scene.solver.k0_factor = glissade_worker::scene::Scalar::Number(k.parse().unwrap());
    }
    let q: Vec<(String, f64)> = vec![("f1".into(), a[2].parse().unwrap()), ("f2".into(), a[3].parse().unwrap())];
    let p: Vec<(String, f64)> = vec![("f1".into(), a[4].parse().unwrap()), ("f2".into(), a[5].parse().unwrap())];
    let mut ps = PointSolver::default();
    let req = |set: &Vec<(String, f64)>, t: f64| SolveRequest {
        set: set.clone(),
        tolerance: Some(t),
        max_iterations: None,
        scale: None,
        record_fields: false,
    };
    let r = ps.solve(&Serial, &scene, &req(&p, 1e-8), None).unwrap().summary;
    let (ra, rb) = (r.qoi["slip_A"].final_value, r.qoi["slip_B"].final_value);
    println!("ref slip_A {ra:.4e} slip_B {rb:.4e}");
    let qo = ps.solve(&Serial, &scene, &req(&q, 2e-4), None).unwrap();
    let variants: Vec<(&str, InterfaceSolution)> = vec![("full", qo.solution.clone())];
    let _unused: Vec<(&str, InterfaceSolution)> = vec![
        ("hat:=s", map(&qo.solution, &|i| i.hat = i.s.clone())),
        ("s:=hat", map(&qo.solution, &|i| i.s = i.hat.clone())),
        (
            "forces only",
            map(&qo.solution, &|i| {
                for sd in i.s.iter_mut().chain(i.hat.iter_mut()) {
                    sd.velocity.iter_mut().for_each(|x| *x = 0.0);
                }
            }),
        ),
        (
            "velocities only",
            map(&qo.solution, &|i| {
                for sd in i.s.iter_mut().chain(i.hat.iter_mut()) {
                    sd.force.iter_mut().for_each(|x| *x = 0.0);
                }
            }),
        ),
    ];
    for (name, init) in &variants {
        for t in [2e-4, 2e-5] {
            let w = ps.solve(&Serial, &scene, &req(&p, t), Some(init)).unwrap().summary;
            let e =
                |s: &glissade_worker::run::SolveSummary, n: &str, r: f64| (s.qoi[n].final_value - r).abs() / r.abs();
            println!(
                "{name:16} tol {t:.0e}: it {:4} (dyn {:4}) errA {:.1e} errB {:.1e}",
                w.iterations,
                w.iterations - w.static_stage.as_ref().unwrap().iterations,
                e(&w, "slip_A", ra),
                e(&w, "slip_B", rb)
            );
        }
    }
}
