//! Long-run fuzzing of every parser on stable Rust: N mutated inputs per
//! parser (default 100 000), each run under `catch_unwind`; inputs that
//! panic or take more than a second of the thread's CPU time are written
//! to `out/fuzz/` (CPU time, not wall time: on a shared machine a stalled
//! thread is not a slow parser). The
//! property tests (`tests/fuzz_parsers.rs`) run the same targets briefly.
//!
//!     cargo run --release --example fuzz_parsers -- 1000000 [SEED] [TARGET]
//!     cargo run --release --example fuzz_parsers -- replay TARGET FILE...

use std::time::{Duration, Instant};

use optistim::fuzzing::{mutate, Rng, Target};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("replay") {
        replay(&args[2..]);
        return;
    }
    let n: u64 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(100_000);
    let seed: u64 = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(1);
    let only = args.get(3).cloned();
    let out = std::path::Path::new("out/fuzz");
    std::fs::create_dir_all(out).expect("out/fuzz");
    let scratch = tempfile::tempdir().expect("scratch dir");
    std::panic::set_hook(Box::new(|_| {}));
    println!("| parser | inputs | accepted | panics | slow (> 1 s CPU) | max CPU ms | wall s |");
    println!("|---|---|---|---|---|---|---|");
    for t in Target::ALL {
        if only.as_deref().is_some_and(|o| o != t.name()) {
            continue;
        }
        let seeds = t.seeds();
        let mut rng = Rng::new(seed);
        let (mut accepted, mut panics, mut slow, mut max) = (0u64, 0u64, 0u64, Duration::ZERO);
        let start = Instant::now();
        let mut corpus = seeds.clone();
        for i in 0..n {
            let base = &corpus[rng.below(corpus.len())];
            let input = mutate(base, &mut rng);
            let t0 = thread_cpu_time();
            let result = std::panic::catch_unwind(|| t.run(&input, scratch.path()));
            let dt = thread_cpu_time().saturating_sub(t0);
            max = max.max(dt);
            match result {
                Ok(ok) => {
                    if ok {
                        accepted += 1;
                        // Accepted mutants widen the search, boundedly.
                        if corpus.len() < 64 {
                            corpus.push(input.clone());
                        }
                    }
                }
                Err(_) => {
                    panics += 1;
                    let _ = std::fs::write(out.join(format!("{}-panic-{i}", t.name())), &input);
                }
            }
            if dt > Duration::from_secs(1) {
                slow += 1;
                let _ = std::fs::write(out.join(format!("{}-slow-{i}", t.name())), &input);
            }
        }
        println!(
            "| {} | {n} | {accepted} | {panics} | {slow} | {:.1} | {:.0} |",
            t.name(),
            max.as_secs_f64() * 1e3,
            start.elapsed().as_secs_f64()
        );
    }
}

/// Runs saved inputs once each through one target and prints the outcome
/// and time: how a `slow` or `panic` file from a long run is reproduced.
fn replay(args: &[String]) {
    let Some(target) = args
        .first()
        .and_then(|name| Target::ALL.into_iter().find(|t| t.name() == name))
    else {
        eprintln!("usage: fuzz_parsers replay TARGET FILE...");
        std::process::exit(2);
    };
    let scratch = tempfile::tempdir().expect("scratch dir");
    for file in &args[1..] {
        let input = std::fs::read(file).unwrap_or_default();
        let t0 = Instant::now();
        let result = std::panic::catch_unwind(|| target.run(&input, scratch.path()));
        let outcome = match result {
            Ok(true) => "accepted",
            Ok(false) => "rejected",
            Err(_) => "PANIC",
        };
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        println!("{file}: {outcome} in {ms:.1} ms ({} bytes)", input.len());
    }
}

/// CPU time used by the calling thread.
fn thread_cpu_time() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec for the call's duration.
    let ok = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0;
    if ok {
        Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
    } else {
        Duration::ZERO
    }
}
