//! The control step allocates nothing: after construction and a few warm-up steps, 200 closed-loop
//! control steps of `nmpc`, `msnmpc` (decoupled) and `msnmpc` (coupled) on the default 2-DOF
//! scenario make no heap allocation. (The rayon-parallel decoupled path, off by default, is not
//! covered: rayon's work stealing may allocate.)

use exompc::config::{ControllerKind, Formulation, Scenario};
use exompc::sim::{build_controller, plant_params, uncertainty, Dof, Plant, Sensors, TwoDof};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Counts allocations made on a thread while that thread has armed the counter.
struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
}

fn count() {
    if ARMED.with(|a| a.get()) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f` on this thread.
fn allocations_in(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    ARMED.with(|a| a.set(true));
    f();
    ARMED.with(|a| a.set(false));
    ALLOCATIONS.load(Ordering::Relaxed) - before
}

/// Closed loop of `s`: 20 warm-up steps, then 200 counted controller steps.
fn count_steps(s: &Scenario, kind: ControllerKind) -> usize {
    let mut controller = build_controller::<TwoDof, 2>(s, kind).expect("controller");
    let mut plant = Plant::new(plant_params::<TwoDof, 2>(s), TwoDof::trajectory(s));
    let mut sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window);
    let mut total = 0;
    for k in 0..220 {
        let t = plant.time();
        let st = *plant.state();
        let force = plant.strap_force();
        let (_raw, meas) = sensors.read(t, &st.robot.q, &st.robot.qd, &force);
        let mut out = None;
        let n = allocations_in(|| out = Some(controller.step(&meas)));
        if k >= 20 {
            total += n;
        }
        plant.step(&out.expect("stepped").torque);
    }
    total
}

#[test]
fn control_steps_do_not_allocate() {
    let mut s = Scenario::default();
    s.multistage.parallel = false;

    s.controller.kind = ControllerKind::Nmpc;
    assert_eq!(count_steps(&s, ControllerKind::Nmpc), 0, "nmpc allocates");

    s.controller.kind = ControllerKind::Msnmpc;
    s.multistage.formulation = Formulation::Decoupled;
    assert_eq!(
        count_steps(&s, ControllerKind::Msnmpc),
        0,
        "msnmpc (decoupled) allocates"
    );

    s.multistage.formulation = Formulation::Coupled;
    assert_eq!(
        count_steps(&s, ControllerKind::Msnmpc),
        0,
        "msnmpc (coupled) allocates"
    );

    // The robust method's filter-aware mode engaged from the first step.
    s.multistage.formulation = Formulation::Decoupled;
    s.controller.robust.filter_aware = exompc::config::FilterAware::Always;
    assert_eq!(
        count_steps(&s, ControllerKind::Msnmpc),
        0,
        "msnmpc (filter-aware) allocates"
    );

    // The counter works.
    assert!(allocations_in(|| drop(std::hint::black_box(vec![1u8; 16]))) > 0);
}

/// Reports the controllers' inline sizes (`cargo test --test alloc -- --nocapture`); the heap
/// buffers are listed in `docs/PERFORMANCE.md`.
#[test]
fn controller_sizes() {
    use exompc::control::{MultiStage, Nmpc};
    let nmpc = std::mem::size_of::<Nmpc<2>>();
    let ms = std::mem::size_of::<MultiStage<2, 6, 4>>();
    eprintln!("size_of Nmpc<2> = {nmpc} B, MultiStage<2, 6, 4> = {ms} B");
    assert!(nmpc > 0 && ms > 0);
}
