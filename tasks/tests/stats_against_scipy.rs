//! `mars_tasks::stats` against SciPy's figures (fixtures/scipy_stats.json, written by
//! fixtures/make_scipy_stats.py): the t quantile, the mean's interval over seeds and the percentile bootstrap.

use mars_tasks::stats::{Bootstrap, mean_over_seeds, t_quantile_975};
use serde_json::Value;

fn fixture() -> Value {
    let text = include_str!("fixtures/scipy_stats.json");
    serde_json::from_str(text).expect("fixture parses")
}

fn f(v: &Value) -> f64 {
    v.as_f64().expect("a number")
}

#[test]
fn t_quantile_is_scipys_to_the_table_rounding() {
    let fx = fixture();
    for (df, want) in fx["t_975"].as_object().expect("a map") {
        let df: usize = df.parse().expect("df");
        let got = t_quantile_975(df);
        // The table holds 3 places up to 30 degrees of freedom; the expansion past it is closer.
        let tol = if df <= 30 { 5e-4 } else { 2e-4 };
        assert!((got - f(want)).abs() <= tol, "df {df}: {got} vs SciPy {}", f(want));
    }
}

#[test]
fn mean_over_seeds_is_scipys_t_interval() {
    for case in fixture()["mean_over_seeds"].as_array().expect("cases") {
        let values: Vec<f64> = case["values"].as_array().expect("values").iter().map(f).collect();
        let e = mean_over_seeds(&values).expect("finite values");
        let (lo, hi) = (f(&case["interval"][0]), f(&case["interval"][1]));
        assert!((e.value - f(&case["mean"])).abs() < 1e-12);
        // Relative to the half-width: the quantile table's rounding is all that differs.
        let tol = 2e-4 * (hi - lo).abs().max(1e-9);
        assert!((e.lo - lo).abs() <= tol && (e.hi - hi).abs() <= tol, "{values:?}: {e} vs SciPy {lo}–{hi}");
    }
}

#[test]
fn bootstrap_intervals_are_scipys_within_resampling_error() {
    for case in fixture()["bootstrap"].as_array().expect("cases") {
        let counts: Vec<usize> = case["counts"].as_array().expect("counts").iter().map(|c| f(c) as usize).collect();
        let n: usize = counts.iter().sum();
        let boot = Bootstrap::new(&counts, 2000, 11);
        let success = boot.estimate(|c| (c[1] + c[2]) as f64 / n as f64);
        let share = boot.estimate(|c| c[1] as f64 / (c[1] + c[2]).max(1) as f64);
        // Both are Monte Carlo estimates of the same percentiles (SciPy's over 20 000 resamples): one rollout's
        // step (1/n) or 0.01, whichever is larger, bounds their difference.
        let tol = (2.0 / n as f64).max(0.01);
        for (what, e, want) in [("success", success, &case["success"]), ("share", share, &case["share_of_first"])] {
            let (lo, hi) = (f(&want[0]), f(&want[1]));
            assert!((e.lo - lo).abs() <= tol && (e.hi - hi).abs() <= tol, "{counts:?} {what}: {e} vs SciPy {lo}–{hi}");
        }
    }
}
