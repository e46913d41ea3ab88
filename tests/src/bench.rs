//! What the benchmark binaries (src/bin/) share: their percentiles and their one JSON line.

use std::process::ExitCode;

/// The `p` quantile of `v` (sorted in place), the nearest rank; NaN when empty.
pub fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Prints a benchmark's JSON object on stdout, or its error on stderr: its exit status.
pub fn report(result: Result<serde_json::Value, crate::synthetic::Error>) -> ExitCode {
    match result {
        Ok(v) => {
            println!("{v}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
