//! How the sampler turns its chain into per-cell marginals p(m_k = 1 | z).

/// p(occupied) of a log-odds value in Q16 (65 536 = 1), from a 129-entry table over
/// −8192 ..= 8192 LSB in steps of 128 (the map's clamp is ±5120): exact at every multiple of 128
/// — every value the default Hähnel model produces — and linearly interpolated between.
pub(crate) fn probability_q16(l: crate::LogOdds) -> u32 {
    let v = i32::from(l.0).clamp(-8192, 8192) + 8192;
    let (i, f) = ((v >> 7) as usize, (v & 127) as u32);
    let a = PROB_TABLE.get(i).copied().unwrap_or(1 << 16);
    let b = PROB_TABLE.get(i + 1).copied().unwrap_or(a);
    (a * (128 - f) + b * f + 64) >> 7
}

static PROB_TABLE: [u32; 129] = build_prob_table();

// Const-evaluated: an out-of-range index fails compilation, not a run.
#[allow(clippy::indexing_slicing)]
const fn build_prob_table() -> [u32; 129] {
    let mut t = [0u32; 129];
    let mut i = 0;
    while i < 129 {
        // p = 1 / (1 + 2^(−l/512)) with l = 128·i − 8192 LSB of ln 2 / 512.
        let x = -((i as f64) * 128.0 - 8192.0) / 512.0 * core::f64::consts::LN_2;
        // exp by squaring a Taylor series of exp(x/64): |x/64| ≤ 0.18.
        let y = x / 64.0;
        let mut term = 1.0;
        let mut e = 1.0;
        let mut k = 1;
        while k < 20 {
            term = term * y / (k as f64);
            e += term;
            k += 1;
        }
        let mut s = 0;
        while s < 6 {
            e *= e;
            s += 1;
        }
        t[i] = (65536.0 / (1.0 + e) + 0.5) as u32;
        i += 1;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Estimator;
    use crate::LogOdds;

    #[test]
    fn rao_blackwellised_averages_need_their_feature() {
        let rb = Estimator::Average {
            shift: 3,
            max_shift: 3,
            reset_on_change: false,
            rao_blackwell: true,
        };
        assert!(rb.rao_blackwellised());
        assert_eq!(rb.available(), cfg!(feature = "rao-blackwell"));
        assert!(Estimator::Counts.available() && !Estimator::Counts.rao_blackwellised());
        let draws = Estimator::Average {
            shift: 3,
            max_shift: 3,
            reset_on_change: false,
            rao_blackwell: false,
        };
        assert!(draws.available() && !draws.rao_blackwellised());
    }

    #[test]
    fn the_average_lengthens_by_one_shift_per_doubling_of_the_age() {
        let e = Estimator::Average {
            shift: 3,
            max_shift: 7,
            reset_on_change: true,
            rao_blackwell: false,
        };
        let shifts: std::vec::Vec<u8> = [0u8, 1, 2, 3, 6, 7, 14, 15, 255]
            .iter()
            .map(|&a| e.shift_at(a))
            .collect();
        assert_eq!(shifts, [3, 4, 4, 5, 5, 6, 6, 7, 7]);
        assert!(e.lengthens());
        let fixed = Estimator::Average {
            shift: 3,
            max_shift: 3,
            reset_on_change: true,
            rao_blackwell: false,
        };
        assert!(!fixed.lengthens());
        assert_eq!(fixed.shift_at(200), 3);
        assert_eq!(Estimator::Counts.shift_at(9), 0);
    }

    #[test]
    fn probability_table_matches_the_float_probability() {
        for raw in (-8192i32..=8192)
            .step_by(7)
            .chain([-5120, -1024, 0, 1024, 5120])
        {
            let l = LogOdds(raw as i16);
            let want = l.probability() * 65536.0;
            let got = f64::from(probability_q16(l));
            // Exact on the table's knots, interpolation error < 0.2 % between them.
            let tol = if raw % 128 == 0 { 1.0 } else { 0.002 * 65536.0 };
            assert!((got - want).abs() <= tol, "{raw}: {got} vs {want}");
        }
        assert_eq!(probability_q16(LogOdds(0)), 32768);
        assert_eq!(
            probability_q16(LogOdds(i16::MAX)),
            probability_q16(LogOdds(8192))
        );
    }
}
