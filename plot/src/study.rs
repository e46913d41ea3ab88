//! The picture of a study's QoI: the response surface that answers `glissade surface --at`
//! (`QoiSurface::of_scene`, fitted to the same points), sampled over the box where it answers,
//! with the scene's units on the axes. The CLI and the web page both call [`Picture::surface`].

use glissade_core::point::DesignPoint;
use std::collections::BTreeMap;

use glissade_core::scene::Scene;
use glissade_core::study::shown;
use glissade_core::study::surrogate::QoiSurface;
use glissade_core::text::same_parameter;

use crate::{Axis, Field, Surface};

/// Nodes per parameter of the sampled grid: over two parameters 41 x 41 predictions (a 121-point
/// surface predicts them in milliseconds), finer than the contours need; over one, a smooth curve.
pub const NODES_2D: usize = 41;
pub const NODES_1D: usize = 201;

/// A point of a surface: its parameters and its QoIs, by name.
pub type Row<'a> = (&'a BTreeMap<String, f64>, &'a BTreeMap<String, f64>);

/// What to picture.
#[derive(Debug, Clone)]
pub struct Picture<'a> {
    /// The study's scene: its parameter ranges bound the box, its units name the axes, it says
    /// which QoIs are norms. None: the stored scene does not parse (the points alone are drawn).
    pub scene: Option<&'a Scene>,
    /// Every parameter of the points, as the surface is fitted over them (the coordinator's
    /// `QuerySurface` names).
    pub names: &'a [String],
    /// The parameters drawn, but for those fixed: the study's swept ones.
    pub swept: &'a [String],
    /// A slice: these parameters at these values; the others (one or two) are drawn.
    pub fixed: &'a [(String, f64)],
    pub qoi: &'a str,
    /// Values below it show as 0 (core::study::resolutions).
    pub resolution: f64,
    /// The tolerance the points were solved to, whose error the surface's standard deviation
    /// carries as `--at`'s does (0: taken as exact).
    pub tolerance: f64,
    pub title: String,
}

impl Picture<'_> {
    /// The surface over the free parameters of the rows in the slice.
    pub fn surface(&self, rows: &[Row]) -> Surface {
        let in_slice = |p: &BTreeMap<String, f64>| {
            self.fixed.iter().all(|(n, v)| p.get(n).is_some_and(|x| same_parameter(*x, *v)))
        };
        let rows: Vec<Row> = rows.iter().copied().filter(|(p, _)| in_slice(p)).collect();
        let free: Vec<&String> = self.swept.iter().filter(|n| !self.fixed.iter().any(|(f, _)| f == *n)).collect();
        let unit = |n: &str| self.scene.and_then(|s| s.unit(n)).map(str::to_owned);
        let points = rows
            .iter()
            .filter_map(|(p, q)| {
                let x: Option<Vec<f64>> = free.iter().map(|n| p.get(*n).copied()).collect();
                Some((x?, shown(*q.get(self.qoi)?, self.resolution)))
            })
            .collect();
        Surface {
            parameters: free.iter().map(|n| Axis::new(*n, unit(n))).collect(),
            qoi: Axis::new(self.qoi, unit(self.qoi)),
            title: self.title.clone(),
            points,
            field: self.field(&rows, &free),
        }
    }

    fn field(&self, rows: &[Row], free: &[&String]) -> Result<Field, String> {
        let scene = self.scene.ok_or("the study's scene does not parse")?;
        if free.is_empty() || free.len() > 2 {
            return Err(format!("{} parameters vary", free.len()));
        }
        if let Some(n) = free.iter().find(|n| !self.names.contains(n)) {
            return Err(format!("`{n}` is not a parameter of the points"));
        }
        let fit_rows: Vec<(Vec<f64>, &BTreeMap<String, f64>)> = rows
            .iter()
            .filter_map(|(p, q)| Some((self.names.iter().map(|n| p.get(n).copied()).collect::<Option<_>>()?, *q)))
            .collect();
        let tolerances = vec![self.tolerance; fit_rows.len()];
        let surface =
            QoiSurface::of_scene(scene, self.names, &fit_rows, &tolerances, self.qoi).map_err(|e| e.to_string())?;
        // every parameter that is not drawn is held where the slice is: fixed, or one value throughout
        let mut held = BTreeMap::new();
        for name in self.names.iter().filter(|n| !free.contains(n)) {
            let value = match self.fixed.iter().find(|(f, _)| f == name) {
                Some((_, v)) => *v,
                None => {
                    let mut values = rows.iter().filter_map(|(p, _)| p.get(name));
                    let first = values.next().copied().unwrap_or(f64::NAN);
                    if values.any(|v| !same_parameter(*v, first)) {
                        return Err(format!("`{name}` varies among the points: fix it to draw a slice"));
                    }
                    first
                }
            };
            held.insert(name.clone(), value);
        }
        let bounds = surface.bounds();
        let free_bounds: Vec<(f64, f64)> = free
            .iter()
            .map(|n| self.names.iter().position(|m| m == *n).map(|k| bounds[k]).ok_or("a parameter without a box"))
            .collect::<Result<_, _>>()?;
        let nodes = if free.len() == 1 { NODES_1D } else { NODES_2D };
        Field::sample(&free_bounds, nodes, |x| {
            let mut point = held.clone();
            point.extend(free.iter().map(|n| (*n).clone()).zip(x.iter().copied()));
            let point = DesignPoint::try_from(point).map_err(|e| e.to_string())?;
            surface.predict(&point).map(|p| (p.mean, p.std)).map_err(|e| e.to_string())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene of our own: two friction parameters with ranges, a slip norm and a displacement.
    const SCENE: &str = include_str!("../tests/two-parameters.toml");

    fn rows(f: impl Fn(f64, f64) -> f64, xs: &[(f64, f64)]) -> Vec<(BTreeMap<String, f64>, BTreeMap<String, f64>)> {
        xs.iter()
            .map(|&(a, b)| {
                let p = BTreeMap::from([("a".to_owned(), a), ("b".to_owned(), b)]);
                let q = BTreeMap::from([("ux".to_owned(), f(a, b)), ("slip".to_owned(), (a - 0.5).max(0.0))]);
                (p, q)
            })
            .collect()
    }

    fn picture<'a>(scene: &'a Scene, names: &'a [String], fixed: &'a [(String, f64)], qoi: &'a str) -> Picture<'a> {
        Picture {
            scene: Some(scene),
            names,
            swept: names,
            fixed,
            qoi,
            resolution: 0.0,
            tolerance: 0.0,
            title: String::new(),
        }
    }

    #[test]
    fn the_picture_is_the_surface_that_answers_at_over_the_scenes_box() {
        let scene = Scene::parse(SCENE).unwrap();
        let names = vec!["a".to_owned(), "b".to_owned()];
        // scattered points well inside the box [0, 1] x [0, 2]: the picture still covers the box
        let xs = [(0.3, 0.5), (0.6, 0.7), (0.4, 1.2), (0.7, 1.4), (0.5, 0.9), (0.35, 1.0)];
        let data = rows(|a, b| a + 0.5 * b, &xs);
        let rows: Vec<Row> = data.iter().map(|(p, q)| (p, q)).collect();
        // points solved to 1e-3, whose error the standard deviation carries as `--at`'s does
        let s = Picture { tolerance: 1e-3, ..picture(&scene, &names, &[], "ux") }.surface(&rows);
        let field = s.field.as_ref().expect("a surface");
        assert_eq!(field.axes[0].first().copied(), Some(0.0));
        assert_eq!(field.axes[0].last().copied(), Some(1.0));
        assert_eq!((field.axes[1][0], field.axes[1][NODES_2D - 1]), (0.0, 2.0));
        assert_eq!(s.points.len(), 6);
        assert_eq!(s.parameters[1], Axis::new("b", Some("m/s".into())));
        assert_eq!(s.qoi, Axis::new("ux", Some("m".into())));
        // the very predictor of `--at`
        let fit: Vec<(Vec<f64>, &BTreeMap<String, f64>)> =
            data.iter().map(|(p, q)| (vec![p["a"], p["b"]], q)).collect();
        let direct = QoiSurface::of_scene(&scene, &names, &fit, &[1e-3; 6], "ux").unwrap();
        let k = 7 + 13 * NODES_2D;
        let at = DesignPoint::try_from(BTreeMap::from([
            ("a".to_owned(), field.axes[0][7]),
            ("b".to_owned(), field.axes[1][13]),
        ]))
        .unwrap();
        let p = direct.predict_within(&at).unwrap();
        assert_eq!((field.mean[k], field.std[k]), (p.mean, p.std));
        let exact = QoiSurface::of_scene(&scene, &names, &fit, &[], "ux").unwrap().predict_within(&at).unwrap();
        assert!(p.std > exact.std, "the points' error widens the error bars: {} against {}", p.std, exact.std);
        // a norm never reads below zero (the same clamp as `--at`'s)
        let slip = picture(&scene, &names, &[], "slip").surface(&rows);
        assert!(slip.field.unwrap().mean.iter().all(|v| *v >= 0.0));
    }

    #[test]
    fn a_slice_draws_one_parameter_and_too_few_points_draw_the_points_alone() {
        let scene = Scene::parse(SCENE).unwrap();
        let names = vec!["a".to_owned(), "b".to_owned()];
        let xs = [(0.2, 1.0), (0.4, 1.0), (0.8, 1.0), (0.5, 0.3)];
        let data = rows(|a, b| a * b, &xs);
        let rows: Vec<Row> = data.iter().map(|(p, q)| (p, q)).collect();
        let fixed = [("b".to_owned(), 1.0)];
        let s = picture(&scene, &names, &fixed, "ux").surface(&rows);
        assert_eq!(s.parameters.len(), 1);
        assert_eq!(s.points.len(), 3, "the points of the slice");
        let field = s.field.unwrap();
        assert_eq!((field.axes[0][0], field.axes[0][NODES_1D - 1]), (0.0, 1.0));
        let one = picture(&scene, &names, &[], "ux").surface(&rows[..1]);
        assert!(one.field.unwrap_err().contains("at least 2 points"));
        // without a scene: the points, and why there is no surface
        let none = Picture { scene: None, ..picture(&scene, &names, &[], "ux") }.surface(&rows);
        assert_eq!(none.points.len(), 4);
        assert!(none.field.is_err());
    }

    /// What a picture costs: the fit and the 41 x 41 predictions, for studies of 25 to 400
    /// points (docs/surrogate.md quotes it). `cargo test --release -p glissade-plot picture_cost
    /// -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn picture_cost() {
        let scene = Scene::parse(SCENE).unwrap();
        let names = vec!["a".to_owned(), "b".to_owned()];
        for n in [5usize, 11, 20, 32, 44] {
            let xs: Vec<(f64, f64)> =
                (0..n * n).map(|k| ((k % n) as f64 / (n - 1) as f64, 2.0 * (k / n) as f64 / (n - 1) as f64)).collect();
            let data = rows(|a, b| (3.0 * a).sin() * b + (a - 0.4).max(0.0), &xs);
            let rows: Vec<Row> = data.iter().map(|(p, q)| (p, q)).collect();
            let start = std::time::Instant::now();
            // points solved to a tolerance, as a study's: their error is carried
            let s = Picture { tolerance: 2e-4, ..picture(&scene, &names, &[], "ux") }.surface(&rows);
            let picture = start.elapsed();
            let start = std::time::Instant::now();
            let svg = crate::surface_svg(&s, (960, 420)).unwrap();
            println!(
                "{} points: fit and {} predictions {:.3} s, SVG {:.3} s, {} kB",
                n * n,
                NODES_2D * NODES_2D,
                picture.as_secs_f64(),
                start.elapsed().as_secs_f64(),
                svg.text.len() / 1000
            );
        }
    }
}
