//! Embree runs every device's builds on the most threads any live device
//! asked for: a timed "one-thread" Embree build must say so when a
//! two-thread device lives, and raylab must not keep such a device itself.
//! One test in its own binary (its own process): other tests' devices would
//! change what it sees.
#![cfg(feature = "embree")]

use raylab::accel::bvh::{BuildParams, BuilderKind};
use raylab::accel::embree::tasking_threads;
use raylab::accel::{build_backend, BackendSpec};
use raylab::scene::builtin::builtin;

#[test]
fn embree_builds_report_the_threads_they_ran_on() {
    let scene = builtin("cornell-water").unwrap();
    let embree = |threads| build_backend(&BackendSpec::embree(threads), &scene).unwrap();
    assert_eq!(tasking_threads(), 0, "no device yet");

    // Alone, a one-thread build runs on one thread.
    let one = embree(1);
    assert_eq!(one.build_threads, 1);
    one.check_build_threads().unwrap();
    drop(one);

    // While a two-thread scene lives, it runs on two, and says so.
    let two = embree(2);
    assert_eq!(two.build_threads, 2);
    let widened = embree(1);
    assert_eq!(widened.build_threads, 2);
    let err = widened.check_build_threads().unwrap_err().to_string();
    assert!(err.contains("ran on 2"), "{err}");
    drop((two, widened));
    assert_eq!(
        tasking_threads(),
        0,
        "devices are released with their scenes"
    );

    // Embree's builder (rtcBuildBVH) keeps its device between builds; a
    // one-thread Embree scene build lets a two-thread one go first.
    let params = BuildParams::for_builder(BuilderKind::EmbreeMedium).with_threads(2);
    let tree = build_backend(&BackendSpec::bvh(params), &scene).unwrap();
    drop(tree);
    assert_eq!(tasking_threads(), 2, "the builder's device is kept");
    let after = embree(1);
    assert_eq!(after.build_threads, 1);
    drop(after);
    assert_eq!(tasking_threads(), 0);
    // And the builder keeps one device at a time.
    for threads in [2, 1, 2, 1] {
        let params = BuildParams::for_builder(BuilderKind::EmbreeMedium).with_threads(threads);
        build_backend(&BackendSpec::bvh(params), &scene).unwrap();
        assert_eq!(tasking_threads(), threads);
    }
}
