//! Values on the nodes of a rectangular grid: bilinear between them, and their level lines by
//! marching squares (the one contour routine of every picture).

/// Values on the nodes of a rectangular grid (uniform or not).
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// z[j * xs.len() + i] at (xs[i], ys[j])
    pub z: Vec<f64>,
}

/// A piece of a level line, between two points in the grid's coordinates.
pub type Segment = [(f64, f64); 2];

impl Grid {
    fn at(&self, i: usize, j: usize) -> f64 {
        self.z[j * self.xs.len() + i]
    }

    /// Bilinear in the cell holding (x, y); clamped to the grid outside it, constant along an axis with a
    /// single value.
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let (i0, i1, tx) = locate(&self.xs, x);
        let (j0, j1, ty) = locate(&self.ys, y);
        (1.0 - tx) * (1.0 - ty) * self.at(i0, j0)
            + tx * (1.0 - ty) * self.at(i1, j0)
            + (1.0 - tx) * ty * self.at(i0, j1)
            + tx * ty * self.at(i1, j1)
    }

    /// Marching squares: the segments of the line where the bilinear surface takes `level`, exact
    /// along every cell edge (so that the line reaches the grid's border where the surface takes
    /// the level there). A saddle cell is split by the mean of its corners.
    pub fn contour(&self, level: f64) -> Vec<Segment> {
        let mut segments = Vec::new();
        for j in 0..self.ys.len().saturating_sub(1) {
            for i in 0..self.xs.len().saturating_sub(1) {
                // corners counter-clockwise, so that edge e runs from corner e to corner e + 1
                let corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
                let p = corners.map(|(a, b)| (self.xs[a], self.ys[b]));
                let v = corners.map(|(a, b)| self.at(a, b));
                let above = v.map(|z| z >= level);
                let mut cross = [None; 4];
                for e in 0..4 {
                    let f = (e + 1) % 4;
                    if above[e] != above[f] {
                        let t = (level - v[e]) / (v[f] - v[e]);
                        cross[e] = Some((p[e].0 + t * (p[f].0 - p[e].0), p[e].1 + t * (p[f].1 - p[e].1)));
                    }
                }
                let edges: Vec<usize> = (0..4).filter(|&e| cross[e].is_some()).collect();
                match edges[..] {
                    [a, b] => segments.extend(pair(&cross, a, b)),
                    [_, _, _, _] => {
                        // saddle: the mean of the corners tells whether corners 0 and 2 are connected, which
                        // isolates corners 1 and 3; corner k lies between edges k - 1 and k
                        let connected = (v.iter().sum::<f64>() / 4.0 >= level) == above[0];
                        let pairs = if connected { [(0, 1), (2, 3)] } else { [(3, 0), (1, 2)] };
                        segments.extend(pairs.into_iter().filter_map(|(a, b)| pair(&cross, a, b)));
                    }
                    _ => {}
                }
            }
        }
        segments
    }
}

/// The segment between the crossings on edges a and b, unless it has shrunk to a point (a corner on the
/// level).
fn pair(cross: &[Option<(f64, f64)>; 4], a: usize, b: usize) -> Option<Segment> {
    match (cross[a], cross[b]) {
        (Some(p), Some(q)) if p != q => Some([p, q]),
        _ => None,
    }
}

/// (i, i + 1, t) with x = (1 - t) xs[i] + t xs[i + 1], t clamped to [0, 1].
fn locate(xs: &[f64], x: f64) -> (usize, usize, f64) {
    if xs.len() < 2 {
        return (0, 0, 0.0);
    }
    let i = xs.partition_point(|&a| a <= x).saturating_sub(1).min(xs.len() - 2);
    let t = ((x - xs[i]) / (xs[i + 1] - xs[i])).clamp(0.0, 1.0);
    (i, i + 1, t)
}

/// Segments joined end to end into polylines: a level line drawn as a few paths instead of a
/// path per cell (issue 47: most of an SVG's bytes). Ends within `tol` of each other meet (two
/// cells compute their shared edge's crossing from its two ends).
pub fn chains(segments: &[Segment], tol: f64) -> Vec<Vec<(f64, f64)>> {
    use std::collections::HashMap;
    let key = |p: (f64, f64)| ((p.0 / tol).round() as i64, (p.1 / tol).round() as i64);
    // each end's segments
    let mut ends: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (k, [a, b]) in segments.iter().enumerate() {
        ends.entry(key(*a)).or_default().push(k);
        ends.entry(key(*b)).or_default().push(k);
    }
    let mut used = vec![false; segments.len()];
    let mut chains = Vec::new();
    for start in 0..segments.len() {
        if used[start] {
            continue;
        }
        used[start] = true;
        let mut chain = std::collections::VecDeque::from(segments[start].to_vec());
        // grow at the back, then at the front
        for back in [true, false] {
            loop {
                let end = if back { chain[chain.len() - 1] } else { chain[0] };
                let next = ends.get(&key(end)).and_then(|ks| ks.iter().copied().find(|&k| !used[k]));
                let Some(k) = next else { break };
                used[k] = true;
                let [a, b] = segments[k];
                let far = if key(a) == key(end) { b } else { a };
                if back { chain.push_back(far) } else { chain.push_front(far) }
            }
        }
        chains.push(chain.into());
    }
    chains
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sampled(xs: &[f64], ys: &[f64], f: impl Fn(f64, f64) -> f64) -> Grid {
        let z = ys.iter().flat_map(|&y| xs.iter().map(move |&x| (x, y))).map(|(x, y)| f(x, y)).collect();
        Grid { xs: xs.to_vec(), ys: ys.to_vec(), z }
    }

    #[test]
    fn bilinear_is_exact_for_bilinear_functions() {
        let f = |x: f64, y: f64| x + y;
        let g = |x: f64, y: f64| 2.0 - 3.0 * x + 0.5 * y + 4.0 * x * y;
        let (xs, ys) = ([0.0, 0.5, 1.0], [0.0, 0.25, 1.0]);
        for h in [&f as &dyn Fn(f64, f64) -> f64, &g] {
            let grid = sampled(&xs, &ys, h);
            for &(x, y) in &[(0.0, 0.0), (1.0, 1.0), (0.3, 0.9), (0.77, 0.1), (0.5, 0.25), (0.25, 0.625)] {
                assert!((grid.value(x, y) - h(x, y)).abs() < 1e-12, "({x}, {y})");
            }
            // clamped outside
            assert!((grid.value(2.0, 2.0) - h(1.0, 1.0)).abs() < 1e-12);
        }
    }

    #[test]
    fn contours_of_a_plane_lie_on_the_level_line_and_reach_the_border() {
        let xs = [0.0, 0.5, 1.0];
        let grid = sampled(&xs, &xs, |x, y| x + y);
        // level 1.0 passes through grid nodes; 0.75 and 1.6 cut edges inside
        for level in [1.0, 0.75, 1.6] {
            let segments = grid.contour(level);
            assert!(!segments.is_empty(), "level {level}");
            for [a, b] in &segments {
                for p in [a, b] {
                    assert!((p.0 + p.1 - level).abs() < 1e-12, "level {level}: {p:?}");
                }
            }
            // the whole chord of the unit square, each piece once: from border to border
            let length: f64 = segments.iter().map(|[a, b]| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()).sum();
            let chord = std::f64::consts::SQRT_2 * if level <= 1.0 { level } else { 2.0 - level };
            assert!((length - chord).abs() < 1e-12, "level {level}: length {length}, expected {chord}");
        }
        assert!(grid.contour(-1.0).is_empty() && grid.contour(3.0).is_empty());
    }

    #[test]
    fn saddle_gives_two_segments() {
        // f = (x - 0.5)(y - 0.5) on the unit square: a saddle in the single cell
        let grid = Grid { xs: vec![0.0, 1.0], ys: vec![0.0, 1.0], z: vec![0.25, -0.25, -0.25, 0.25] };
        for level in [0.1, -0.1, 0.0] {
            assert_eq!(grid.contour(level).len(), 2, "level {level}");
        }
    }

    #[test]
    fn segments_join_into_lines() {
        // a circle's level line on a fine grid (through no node): one closed chain, every segment once
        let xs: Vec<f64> = (0..=40).map(|k| k as f64 / 20.0 - 1.0).collect();
        let grid = sampled(&xs, &xs, |x, y| x * x + y * y);
        let segments = grid.contour(0.4321);
        let joined = chains(&segments, 1e-9);
        assert_eq!(joined.len(), 1, "{} chains", joined.len());
        assert_eq!(joined[0].len(), segments.len() + 1, "closed: its first point again at its end");
        // a line crossing the box and a piece apart: two chains
        let two = [[(0.0, 0.0), (1.0, 0.0)], [(5.0, 5.0), (6.0, 5.0)], [(1.0, 0.0), (2.0, 1.0)]];
        let joined = chains(&two, 1e-9);
        assert_eq!(joined.len(), 2);
        assert_eq!(joined[0], [(0.0, 0.0), (1.0, 0.0), (2.0, 1.0)]);
    }
}
