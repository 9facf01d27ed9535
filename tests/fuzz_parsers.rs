//! Every parser of user input, fed real files mutated at random and plain
//! random bytes: `Ok` or an error, never a panic, and no single allocation
//! beyond a stated bound (a counting allocator in this test binary).
//! Long runs: `cargo run --release --example fuzz_parsers -- 1000000`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use optistim::fuzzing::{mutate, Rng, Target};
use proptest::prelude::*;

/// The largest single allocation any parser may make on a fuzzed input of
/// a few kB to a few hundred kB (the seeds): far above what a valid input
/// of that size needs, far below what a wrapped size asks for.
const MAX_ALLOCATION: usize = 256 << 20;

struct Counting;
static LARGEST: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator, only recording sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn check(target: Target, input: &[u8]) {
    let dir = tempfile::tempdir().unwrap();
    target.run(input, dir.path());
    let largest = LARGEST.load(Ordering::Relaxed);
    assert!(
        largest <= MAX_ALLOCATION,
        "{}: an allocation of {largest} bytes",
        target.name()
    );
}

/// The seeds themselves are accepted: the mutations start from valid input.
#[test]
fn seeds_parse() {
    let dir = tempfile::tempdir().unwrap();
    for t in Target::ALL {
        for (i, seed) in t.seeds().iter().enumerate() {
            // The bundled scene's maps (seed 1) are not in the scratch
            // directory.
            if t != Target::SceneToml || i != 1 {
                assert!(t.run(seed, dir.path()), "{} seed {i} rejected", t.name());
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn mutated_real_inputs_never_panic(target in 0..Target::ALL.len(), seed in any::<u64>()) {
        let t = Target::ALL[target];
        let mut rng = Rng::new(seed);
        let seeds = t.seeds();
        let input = mutate(&seeds[rng.below(seeds.len())], &mut rng);
        check(t, &input);
    }

    #[test]
    fn random_bytes_never_panic(target in 0..Target::ALL.len(), bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        check(Target::ALL[target], &bytes);
    }
}
