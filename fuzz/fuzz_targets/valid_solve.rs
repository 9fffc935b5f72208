//! Target 2: structured VALID problems with extreme-but-allowed values
//! (the validation limits as bounds). Every solve must end within its
//! budget with a status and pass `common::check_result`.
#![no_main]

use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use arbitrary::Arbitrary;
use ilqr_service::models::MODELS;
use ilqr_service::problem::{
    Integrator, MAX_CONTROL, MAX_DT, MAX_ITERATIONS, MAX_OBSTACLES, MAX_STATE, MAX_WEIGHT, Method,
    Obstacle, ProblemSpec,
};
use libfuzzer_sys::fuzz_target;

fn extreme() -> bool {
    static E: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *E.get_or_init(|| std::env::var_os("FUZZ_EXTREME").is_some())
}

#[path = "common.rs"]
mod common;

/// A number inside a field's range, biased to its edges.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum Num {
    Lo,
    Hi,
    Zero,
    Tiny,
    One,
    /// Log-uniform magnitude between the range's ends (sign from the bool
    /// where the range is symmetric).
    Log(u16, bool),
    /// Any f64; used when it lies in range, else folded onto Log.
    Raw(f64),
}

impl Num {
    /// Map into [lo, hi] (lo ≥ 0) or, when `symmetric`, into [-hi, hi].
    fn get(self, lo: f64, hi: f64, symmetric: bool) -> f64 {
        let ok = |x: f64| {
            x.is_finite()
                && if symmetric {
                    x.abs() <= hi
                } else {
                    (lo..=hi).contains(&x)
                }
        };
        let v = match self {
            Num::Lo => {
                if symmetric {
                    -hi
                } else {
                    lo
                }
            }
            Num::Hi => hi,
            Num::Zero => 0.0,
            Num::Tiny => f64::from_bits(1), // 5e-324
            Num::One => 1.0,
            // FUZZ_EXTREME=1: only the ends of each range (and their
            // neighbours), to hunt overflow at the limits.
            Num::Log(t, neg) if extreme() => {
                let a = if lo > 0.0 { lo } else { f64::from_bits(1) };
                let m = match t % 4 {
                    0 => a,
                    1 => hi,
                    2 => hi * (1.0 - 1e-9),
                    _ => a * 1.5,
                };
                if symmetric && neg { -m } else { m }
            }
            Num::Log(t, neg) => {
                let a = if lo > 0.0 { lo } else { 1e-12 };
                let f = f64::from(t) / f64::from(u16::MAX);
                let m = (a.ln() + f * (hi.ln() - a.ln())).exp().clamp(a, hi);
                if symmetric && neg { -m } else { m }
            }
            Num::Raw(x) => x,
        };
        if ok(v) {
            v
        } else if symmetric {
            0.0
        } else {
            lo
        }
    }
}

/// Entries enough for any model's vectors (the longest state has 6).
const MAX_LEN: usize = 6;

#[derive(Arbitrary, Debug)]
struct Input {
    /// Which model (modulo their number).
    model: u8,
    rk4: bool,
    /// The model's parameters, in its order, each in its own range.
    parameters: [Num; MAX_LEN],
    dt: Num,
    horizon: u16,
    long: bool,
    x0: [Num; MAX_LEN],
    goal: [Num; MAX_LEN],
    wq: [Num; MAX_LEN],
    wr: [Num; MAX_LEN],
    wf: [Num; MAX_LEN],
    obstacles: Vec<([Num; 2], Num)>,
    /// Initial controls: a pattern repeated over the horizon, or the
    /// model's rest controls.
    controls: Option<Vec<[Num; MAX_LEN]>>,
    max_iterations: u16,
    tolerance: Num,
    budget_ms: u8,
    /// DDP (the dynamics' second derivatives) instead of iLQR.
    ddp: bool,
}

fuzz_target!(|input: Input| {
    let model = MODELS[usize::from(input.model) % MODELS.len()];
    let mut spec = ProblemSpec::default_for(model);
    for (i, p) in model.parameters().iter().enumerate() {
        let value = input.parameters[i].get(p.minimum, p.maximum, false);
        spec.model.parameters[i] = (p.name.to_owned(), value);
    }
    spec.integrator = if input.rk4 {
        Integrator::Rk4
    } else {
        Integrator::Euler
    };
    spec.dt = input.dt.get(1e-300, MAX_DT, false);
    if spec.dt <= 0.0 {
        spec.dt = 1e-300;
    }
    // Mostly short horizons so execs are fast; sometimes up to 10000.
    spec.horizon = if input.long {
        1 + usize::from(input.horizon) % 10_000
    } else {
        1 + usize::from(input.horizon) % 300
    };
    let (nx, nu) = (model.state().len(), model.control().len());
    let pick = |from: &[Num; MAX_LEN], n: usize, lo: f64, hi: f64, symmetric: bool| -> Vec<f64> {
        from[..n].iter().map(|x| x.get(lo, hi, symmetric)).collect()
    };
    spec.initial_state = pick(&input.x0, nx, 0.0, MAX_STATE, true);
    spec.goal_state = pick(&input.goal, nx, 0.0, MAX_STATE, true);
    spec.weights.state = pick(&input.wq, nx, 0.0, MAX_WEIGHT, false);
    spec.weights.terminal = pick(&input.wf, nx, 0.0, MAX_WEIGHT, false);
    spec.weights.control = pick(&input.wr, nu, 0.0, MAX_WEIGHT, false);
    spec.obstacles = input
        .obstacles
        .iter()
        .take(MAX_OBSTACLES)
        .map(|(c, w)| {
            Obstacle::point(
                [
                    c[0].get(0.0, MAX_STATE, true),
                    c[1].get(0.0, MAX_STATE, true),
                ],
                w.get(0.0, MAX_WEIGHT, false),
            )
        })
        .collect();
    spec.initial_controls = input.controls.as_ref().filter(|p| !p.is_empty()).map(|p| {
        (0..spec.horizon)
            .map(|k| pick(&p[k % p.len()], nu, 0.0, MAX_CONTROL, true))
            .collect()
    });
    spec.solver.max_iterations = usize::from(input.max_iterations) % (MAX_ITERATIONS + 1);
    let tol = input.tolerance.get(0.0, 1.0, false);
    spec.solver.tolerance = if tol >= 1.0 { 0.999 } else { tol };
    let budget_ms = 1 + u64::from(input.budget_ms) % 30;
    spec.solver.time_limit_ms = Some(budget_ms);
    spec.solver.method = if input.ddp { Method::Ddp } else { Method::Ilqr };

    let limits = common::service_limits();
    if let Err(e) = spec.validate(&limits) {
        // A harness bug, not a finding.
        panic!("harness built an invalid problem: {:?}", e.errors);
    }
    // Round trip through the wire format, as a client would send it.
    let body = serde_json::to_vec(&spec).expect("spec serialises");
    let spec = ilqr_service::problem::parse(&body).expect("a valid spec parses back");

    let budget = Duration::from_millis(budget_ms);
    let started = Instant::now();
    match ilqr_service::solve::solve(&spec, Some(budget), &AtomicBool::new(false)) {
        Ok(r) => {
            if std::env::var_os("FUZZ_STATS").is_some() {
                eprintln!(
                    "STAT {:?} it={} N={} conv={:?}",
                    r.status,
                    r.iterations,
                    spec.horizon,
                    r.convexified_after_iteration.is_some()
                );
            }
            common::check_time(started, budget, &r, "valid_solve");
            common::check_result(&r, "valid_solve");
        }
        Err(u) => panic!("validated problem unsolvable: {:?}", u.0),
    }
});
