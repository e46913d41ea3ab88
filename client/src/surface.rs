//! A response surface as `glissade surface` prints it: a table, CSV or JSON, from the
//! coordinator's QuerySurface reply. CSV values are printed in Rust's shortest round-trip form
//! (`{:e}` for QoIs and eta), so a CSV or JSON reader gets back exactly the stored numbers.

use std::collections::BTreeMap;

use glissade_proto::v1;

use crate::names::point_state_name;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SurfaceError {
    #[error("unknown QoI `{name}`: the scene's are {}", known.join(", "))]
    UnknownQoi { name: String, known: Vec<String> },
    #[error("--fix {name}: `{name}` is not a swept parameter of the study (they are {})", known.join(", "))]
    UnknownParameter { name: String, known: Vec<String> },
    #[error("--fix {spec}: expected NAME=VALUE, e.g. --fix f2=0.15")]
    FixSyntax { spec: String },
    #[error("--fix {spec}: `{value}` is not a number")]
    FixNotANumber { spec: String, value: String },
    #[error("--fix {spec}: the value must be finite")]
    FixNotFinite { spec: String },
}

/// One point of the surface.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceRow {
    /// In [`SurfaceTable::parameters`] order.
    pub parameters: Vec<f64>,
    /// In [`SurfaceTable::qoi`] order; None where the point has no value (not done).
    pub qoi: Vec<Option<f64>>,
    pub iterations: u64,
    pub error_indicator: f64,
    pub converged: bool,
    pub state: &'static str,
}

/// The points of a surface with the columns asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceTable {
    pub scene_hash: String,
    pub parameters: Vec<String>,
    pub qoi: Vec<String>,
    pub rows: Vec<SurfaceRow>,
    /// Per QoI column, the smallest value the solves resolve (0: all): smaller values read 0 in
    /// the table and the pictures, and keep their stored value in CSV and JSON.
    pub resolution: Vec<f64>,
    /// Significant digits of the QoIs for people (core::text::qoi_digits, the coordinator's).
    pub digits: usize,
    /// The unit of each parameter that declares one and of each QoI (the coordinator's).
    pub units: BTreeMap<String, String>,
}

impl SurfaceTable {
    /// The table of `reply` with one QoI (`Some`) or all of them.
    pub fn new(reply: &v1::QuerySurfaceReply, qoi: Option<&str>) -> Result<Self, SurfaceError> {
        let columns = match qoi {
            Some(name) if !reply.qoi.iter().any(|q| q == name) => {
                return Err(SurfaceError::UnknownQoi { name: name.to_owned(), known: reply.qoi.clone() });
            }
            Some(name) => vec![name.to_owned()],
            None => reply.qoi.clone(),
        };
        let rows = reply
            .points
            .iter()
            .map(|p| SurfaceRow {
                parameters: reply.parameters.iter().map(|n| p.parameters.get(n).copied().unwrap_or(f64::NAN)).collect(),
                qoi: columns.iter().map(|q| p.qoi.get(q).copied()).collect(),
                iterations: p.iterations,
                error_indicator: p.error_indicator,
                converged: p.converged,
                state: point_state_name(p.state),
            })
            .collect();
        // what the solves resolve and how many digits, as the coordinator says (the one rule of
        // the CLI, the web page and Python: core::text::qoi_value)
        let resolution = columns.iter().map(|q| reply.resolutions.get(q).copied().unwrap_or(0.0)).collect();
        Ok(Self {
            scene_hash: reply.scene_hash.clone(),
            parameters: reply.parameters.clone(),
            qoi: columns,
            rows,
            resolution,
            digits: if reply.digits > 0 { reply.digits as usize } else { 6 },
            units: reply.units.clone(),
        })
    }

    /// The same table with only the parameter columns named in `names` (in that order): a
    /// scene-wide query returns every parameter, a study's surface is over its swept ones.
    pub fn restricted_to(mut self, names: &[String]) -> Self {
        let keep: Vec<usize> = names.iter().filter_map(|n| self.parameters.iter().position(|p| p == n)).collect();
        for row in &mut self.rows {
            row.parameters = keep.iter().map(|&i| row.parameters[i]).collect();
        }
        self.parameters = keep.iter().map(|&i| self.parameters[i].clone()).collect();
        self
    }

    /// Parameters, QoIs, iterations, eta, state; a header line first.
    pub fn to_csv(&self) -> String {
        let rows = self.rows.iter().map(|row| self.cells(row, true));
        glissade_core::text::csv_table(std::iter::once(self.header(false)).chain(rows))
    }

    /// `{"scene_hash", "parameters", "qoi", "units", "points": [{"parameters": {..}, "qoi": {..}, ...}]}`.
    pub fn to_json(&self) -> serde_json::Value {
        let points: Vec<serde_json::Value> = self
            .rows
            .iter()
            .map(|r| {
                let parameters: serde_json::Map<String, serde_json::Value> =
                    self.parameters.iter().cloned().zip(r.parameters.iter().map(|&v| v.into())).collect();
                let qoi: serde_json::Map<String, serde_json::Value> =
                    self.qoi.iter().zip(&r.qoi).filter_map(|(name, v)| v.map(|v| (name.clone(), v.into()))).collect();
                serde_json::json!({
                    "parameters": parameters,
                    "qoi": qoi,
                    "iterations": r.iterations,
                    "error_indicator": glissade_core::text::measured_eta(r.error_indicator),
                    "converged": r.converged,
                    "state": r.state,
                })
            })
            .collect();
        serde_json::json!({
            "scene_hash": self.scene_hash,
            "parameters": self.parameters,
            "qoi": self.qoi,
            "units": self.units,
            "points": points,
        })
    }

    /// Aligned columns for people; QoIs with the digits their tolerance resolves.
    pub fn to_text(&self) -> String {
        let header = self.header(true);
        let body: Vec<Vec<String>> = self.rows.iter().map(|r| self.cells(r, false)).collect();
        let widths: Vec<usize> = (0..header.len())
            .map(|c| body.iter().map(|row| row[c].len()).chain([header[c].len()]).max().unwrap_or(0))
            .collect();
        let line = |cells: &[String]| {
            cells
                .iter()
                .zip(&widths)
                .map(|(c, w)| format!("{c:>w$}"))
                .collect::<Vec<_>>()
                .join("  ")
                .trim_end()
                .to_owned()
        };
        let mut out = line(&header) + "\n";
        for row in &body {
            out += &line(row);
            out.push('\n');
        }
        out
    }

    /// The columns' names; `units`: with the unit after each that has one (`slip_A (m)`: for
    /// people; a CSV's header keeps the bare names a program looks up).
    fn header(&self, units: bool) -> Vec<String> {
        let fixed = ["iterations", "eta", "state"].map(String::from);
        let name = |n: &String| match self.units.get(n) {
            Some(u) if units => format!("{n} ({u})"),
            _ => n.clone(),
        };
        self.parameters.iter().chain(&self.qoi).map(name).chain(fixed).collect()
    }

    /// `exact`: shortest round-trip numbers (files); else rounded ones (people).
    fn cells(&self, row: &SurfaceRow, exact: bool) -> Vec<String> {
        let number = |x: f64, digits: usize| if exact { format!("{x:e}") } else { format!("{x:.digits$e}") };
        row.parameters
            .iter()
            .map(|&p| if exact { format!("{p}") } else { glissade_core::text::parameter(p) })
            .chain(row.qoi.iter().zip(&self.resolution).map(|(v, &r)| {
                v.map(|x| if exact { number(x, 0) } else { glissade_core::text::qoi_value(x, self.digits, r) })
                    .unwrap_or_default()
            }))
            .chain([
                row.iterations.to_string(),
                glissade_core::text::measured_eta(row.error_indicator).map(|e| number(e, 3)).unwrap_or_default(),
                row.state.to_owned(),
            ])
            .collect()
    }

    /// The (swept parameters, QoI value) pairs of the done points, for a picture of column `qoi`
    /// (values below the resolution: 0).
    pub fn values(&self, qoi: usize) -> Vec<(Vec<f64>, f64)> {
        let shown = |v| glissade_core::study::shown(v, self.resolution[qoi]);
        self.rows.iter().filter_map(|r| r.qoi[qoi].map(|v| (r.parameters.clone(), shown(v)))).collect()
    }
}

/// Predictions of a surface's QoIs at given points (`glissade surface --at`), as the coordinator
/// computed them.
#[derive(Debug, Clone)]
pub struct Predictions {
    pub parameters: Vec<String>,
    pub qoi: Vec<String>,
    pub points: Vec<v1::SurfacePrediction>,
    pub units: BTreeMap<String, String>,
    /// QoIs that are norms (a slip without a component, never negative): where their band of 2
    /// sd reaches zero, the text says that sticking is not ruled out
    pub norms: std::collections::BTreeSet<String>,
    /// Significant digits of a mean (the table's).
    pub digits: usize,
    /// Below it a mean reads 0 (the coordinator's resolutions: a stuck slip's round-off).
    pub resolutions: BTreeMap<String, f64>,
}

impl Predictions {
    /// The predictions of `reply` for the QoIs of `table`.
    pub fn new(reply: &v1::QuerySurfaceReply, table: &SurfaceTable) -> Self {
        Self {
            parameters: table.parameters.clone(),
            qoi: table.qoi.clone(),
            points: reply.predictions.clone(),
            units: table.units.clone(),
            norms: Default::default(),
            digits: table.digits,
            resolutions: reply.resolutions.clone().into_iter().collect(),
        }
    }

    fn get(&self, point: &v1::SurfacePrediction, qoi: &str) -> (f64, f64, u32) {
        point.qoi.get(qoi).map_or((f64::NAN, f64::NAN, 0), |p| (p.mean, p.std, p.fitted_points))
    }

    /// One line per point and QoI: `f1=0.137 f2=0.151  slip_A = 1.2340e-5 +- 2.10e-7 m`.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        let mut fitted = BTreeMap::new();
        for point in &self.points {
            let at: Vec<String> = self
                .parameters
                .iter()
                .map(|n| format!("{n}={}", point.parameters.get(n).unwrap_or(&f64::NAN)))
                .collect();
            for q in &self.qoi {
                let (mean, std, n) = self.get(point, q);
                fitted.insert(q.clone(), n);
                let unit = self.units.get(q).map(|u| format!(" {u}")).unwrap_or_default();
                // a band of 2 sd that holds zero: a norm may stick there, another QoI's sign is
                // not known there (issue 47: 4.76e-6 +- 8.94e-6 said nothing)
                let zero = match point.qoi.get(q) {
                    Some(p) if self.norms.contains(q) && mean - 2.0 * std <= 0.0 => {
                        format!("  (2 sd: [{:.2e}, {:.2e}]{unit}; sticking not ruled out here)", p.low, p.high)
                    }
                    Some(p) if !self.norms.contains(q) && mean.abs() < 2.0 * std => {
                        format!("  (2 sd: [{:.2e}, {:.2e}]{unit}; its sign is not known here)", p.low, p.high)
                    }
                    _ => String::new(),
                };
                let resolution = self.resolutions.get(q).copied().unwrap_or(0.0);
                let mean = glissade_core::text::qoi_value(mean, self.digits, resolution);
                out += &format!("{}  {q} = {mean} +- {std:.2e}{unit}{zero}\n", at.join(" "));
            }
        }
        let fitted: Vec<String> = fitted.iter().map(|(q, n)| format!("{q} {n}")).collect();
        out += &format!(
            "(mean +- 1 standard deviation of a Gaussian process fitted to the points with a value: {})\n",
            fitted.join(", ")
        );
        out
    }

    /// `{"parameters": [...], "units": {...}, "points": [{"at": {...}, "qoi": {"slip_A": {"mean": m,
    /// "std": s, "fitted_points": n}}}]}`.
    pub fn to_json(&self) -> serde_json::Value {
        let points: Vec<serde_json::Value> = self
            .points
            .iter()
            .map(|point| {
                let qoi: serde_json::Map<String, serde_json::Value> = self
                    .qoi
                    .iter()
                    .map(|q| {
                        let (mean, std, n) = self.get(point, q);
                        let (low, high) = point.qoi.get(q).map_or((f64::NAN, f64::NAN), |p| (p.low, p.high));
                        let fields = serde_json::json!({ "mean": mean, "std": std, "fitted_points": n, "low": low, "high": high });
                        (q.clone(), fields)
                    })
                    .collect();
                serde_json::json!({ "at": point.parameters, "qoi": qoi })
            })
            .collect();
        serde_json::json!({ "parameters": self.parameters, "units": self.units, "points": points })
    }
}

/// Parses `--fix NAME=VALUE` and checks the name against the swept parameters.
pub fn parse_fixed(spec: &str, swept: &[String]) -> Result<(String, f64), SurfaceError> {
    let (name, value) = spec.split_once('=').ok_or_else(|| SurfaceError::FixSyntax { spec: spec.to_owned() })?;
    let name = name.trim();
    let value: f64 = value
        .trim()
        .parse()
        .map_err(|_| SurfaceError::FixNotANumber { spec: spec.to_owned(), value: value.trim().to_owned() })?;
    if !value.is_finite() {
        return Err(SurfaceError::FixNotFinite { spec: spec.to_owned() });
    }
    if !swept.iter().any(|s| s == name) {
        return Err(SurfaceError::UnknownParameter { name: name.to_owned(), known: swept.to_vec() });
    }
    Ok((name.to_owned(), value))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply() -> v1::QuerySurfaceReply {
        let point = |f1: f64, slip: Option<f64>, state: v1::PointState| v1::SurfacePoint {
            parameters: [("f1".to_owned(), f1)].into(),
            qoi: slip.into_iter().map(|s| ("slip_A".to_owned(), s)).chain([("x".to_owned(), 1.0)]).collect(),
            iterations: 12,
            error_indicator: 1e-4,
            converged: slip.is_some(),
            state: state.into(),
        };
        v1::QuerySurfaceReply {
            units: [("slip_A".to_owned(), "m".to_owned())].into(),
            scene_hash: "ab".into(),
            parameters: vec!["f1".into()],
            qoi: vec!["slip_A".into(), "x".into()],
            points: vec![point(0.1, Some(0.1 + 0.2), v1::PointState::Done), point(0.2, None, v1::PointState::Failed)],
            predictions: vec![v1::SurfacePrediction {
                parameters: [("f1".to_owned(), 0.15)].into(),
                qoi: [(
                    "slip_A".to_owned(),
                    v1::QoiPrediction { mean: 0.25, std: 0.125, fitted_points: 1, low: 0.0, high: 0.5 },
                )]
                .into(),
            }],
            resolutions: [("slip_A".to_owned(), 1e-9), ("x".to_owned(), 0.0)].into(),
            digits: 4,
        }
    }

    #[test]
    fn predictions_print_the_mean_and_the_standard_deviation() {
        let t = SurfaceTable::new(&reply(), Some("slip_A")).unwrap();
        let p = Predictions::new(&reply(), &t);
        assert_eq!(p.to_text().lines().next(), Some("f1=0.15  slip_A = 2.500e-1 +- 1.25e-1 m"), "{}", p.to_text());
        // a norm whose band reaches zero says so; 0.25 - 2 x 0.125 = 0
        let mut norm = Predictions::new(&reply(), &t);
        norm.norms.insert("slip_A".into());
        assert!(
            norm.to_text()
                .lines()
                .next()
                .is_some_and(|l| l.ends_with("m  (2 sd: [0.00e0, 5.00e-1] m; sticking not ruled out here)")),
            "{}",
            norm.to_text()
        );
        // another QoI whose band holds zero: its sign is not known there; a mean below the
        // resolution reads 0
        let mut unsure = reply();
        unsure.predictions[0].qoi.insert(
            "x".into(),
            v1::QoiPrediction { mean: 4.76e-6, std: 8.94e-6, fitted_points: 1, low: -1.312e-5, high: 2.264e-5 },
        );
        unsure.predictions[0].qoi.get_mut("slip_A").unwrap().mean = 2.9e-15;
        let all = SurfaceTable::new(&unsure, None).unwrap();
        let text = Predictions::new(&unsure, &all).to_text();
        assert!(
            text.contains("x = 4.760e-6 +- 8.94e-6  (2 sd: [-1.31e-5, 2.26e-5]; its sign is not known here)"),
            "{text}"
        );
        assert!(text.contains("slip_A = 0 +- 1.25e-1 m"), "{text}");
        let json = p.to_json();
        assert_eq!(json["points"][0]["at"]["f1"], 0.15);
        assert_eq!(json["points"][0]["qoi"]["slip_A"]["std"], 0.125);
        assert_eq!(
            (&json["points"][0]["qoi"]["slip_A"]["low"], &json["points"][0]["qoi"]["slip_A"]["high"]),
            (&0.0.into(), &0.5.into())
        );
    }

    #[test]
    fn csv_and_json_give_back_the_exact_values() {
        let t = SurfaceTable::new(&reply(), Some("slip_A")).unwrap();
        let csv = t.to_csv();
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some("f1,slip_A,iterations,eta,state"));
        let first: Vec<&str> = lines.next().unwrap().split(',').collect();
        assert_eq!(first[1].parse::<f64>().unwrap().to_bits(), (0.1f64 + 0.2).to_bits());
        assert_eq!(lines.next(), Some("0.2,,12,1e-4,failed"));
        let json = t.to_json();
        assert_eq!(json["points"][0]["qoi"]["slip_A"].as_f64(), Some(0.1 + 0.2));
        assert!(json["points"][1]["qoi"].as_object().unwrap().is_empty());
        assert_eq!(t.values(0), vec![(vec![0.1], 0.1 + 0.2)]);
        assert!(t.to_text().lines().count() == 3);
        // for people, the digits the coordinator says (4 at a tolerance of 1e-3) and exact zeros
        // below the resolution it says
        assert!(t.to_text().lines().nth(1).is_some_and(|l| l.contains(" 3.000e-1 ")), "{}", t.to_text());
        let mut stuck = reply();
        stuck.points[0].qoi.insert("slip_A".into(), 4.67e-21);
        let stuck = SurfaceTable::new(&stuck, Some("slip_A")).unwrap();
        assert!(
            stuck.to_text().lines().nth(1).is_some_and(|l| l.split_whitespace().nth(1) == Some("0")),
            "{}",
            stuck.to_text()
        );
        assert!(stuck.to_csv().contains("4.67e-21"), "the file keeps the value: {}", stuck.to_csv());
        // units: in the table's header and the JSON, not in the CSV's header a program reads
        assert_eq!(json["units"]["slip_A"], "m");
        assert!(t.to_text().lines().next().is_some_and(|h| h.contains("slip_A (m)")), "{}", t.to_text());
    }

    #[test]
    fn unknown_qoi_and_parameter_are_named() {
        let e = SurfaceTable::new(&reply(), Some("slip_C")).unwrap_err();
        assert_eq!(e.to_string(), "unknown QoI `slip_C`: the scene's are slip_A, x");
        assert_eq!(SurfaceTable::new(&reply(), None).unwrap().qoi.len(), 2);
        let swept = ["f1".to_owned(), "f2".to_owned()];
        assert_eq!(parse_fixed("f2=0.15", &swept), Ok(("f2".into(), 0.15)));
        assert!(parse_fixed("f3=0.1", &swept).unwrap_err().to_string().contains("not a swept parameter"));
        assert!(parse_fixed("f2", &swept).is_err());
        assert!(parse_fixed("f2=abc", &swept).is_err());
        assert!(parse_fixed("f2=NaN", &swept).is_err());
    }
}
