//! Statistics the filters and the solvers gate with, and the tools report
//! with: the standard normal and χ² quantiles, and percentiles.

#[allow(clippy::excessive_precision)]
/// Standard normal quantile (Acklam's rational approximation, |ε| < 1.2e-9).
pub fn normal_quantile(p: f64) -> f64 {
    let a = [
        -3.969683028665376e+01,
        2.209460984245205e+02,
        -2.759285104469687e+02,
        1.383577518672690e+02,
        -3.066479806614716e+01,
        2.506628277459239e+00,
    ];
    let b = [
        -5.447609879822406e+01,
        1.615858368580409e+02,
        -1.556989798598866e+02,
        6.680131188771972e+01,
        -1.328068155288572e+01,
    ];
    let c = [
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e+00,
        -2.549732539343734e+00,
        4.374664141464968e+00,
        2.938163982698783e+00,
    ];
    let d = [
        7.784695709041462e-03,
        3.224671290700398e-01,
        2.445134137142996e+00,
        3.754408661907416e+00,
    ];
    let pl = 0.02425;
    if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
            / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q
            / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)
    } else {
        -normal_quantile(1.0 - p)
    }
}

/// Quantile of the χ² distribution with `dof` degrees of freedom. Exact
/// table values at 95% for 1–10 dof; the Wilson–Hilferty cube
/// approximation otherwise (relative error < 0.5% for dof ≥ 3).
pub fn chi2_quantile(p: f64, dof: usize) -> f64 {
    const Q95: [f64; 10] = [
        3.841459, 5.991465, 7.814728, 9.487729, 11.070498, 12.591587, 14.067140, 15.507313, 16.918978, 18.307038,
    ];
    if (p - 0.95).abs() < 1e-12 && (1..=10).contains(&dof) {
        return Q95[dof - 1];
    }
    let k = dof.max(1) as f64;
    let z = normal_quantile(p);
    let h = 2.0 / (9.0 * k);
    k * (1.0 - h + z * h.sqrt()).powi(3).max(0.0)
}

/// The value at fraction `p` (0..1) of `v` once sorted, by nearest rank
/// (`v` is sorted in place, without allocating: values equal under
/// `total_cmp` are the same bits, so an unstable sort gives the same
/// answer); `None` if `v` is empty.
pub fn percentile(v: &mut [f64], p: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_unstable_by(|a, b| a.total_cmp(b));
    Some(v[((v.len() - 1) as f64 * p).round() as usize])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_and_normal_quantiles() {
        assert!((chi2_quantile(0.95, 3) - 7.814728).abs() < 1e-6);
        // χ²(0.975, 30) = 46.979, χ²(0.025, 30) = 16.791.
        assert!((chi2_quantile(0.975, 30) - 46.979).abs() < 0.1);
        assert!((chi2_quantile(0.025, 30) - 16.791).abs() < 0.1);
        assert!((normal_quantile(0.975) - 1.959964).abs() < 1e-6);
    }

    #[test]
    fn percentile_by_nearest_rank() {
        let mut v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(percentile(&mut v, 0.5), Some(3.0));
        assert_eq!(percentile(&mut v, 0.99), Some(5.0));
        assert_eq!(percentile(&mut v, 0.0), Some(1.0));
        // (5 − 1) · 0.4 = 1.6 rounds to rank 2.
        assert_eq!(percentile(&mut v, 0.4), Some(3.0));
        assert_eq!(percentile(&mut [], 0.5), None);
    }
}
