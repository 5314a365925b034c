//! exompc's closed loop on a Cortex-M7 (QEMU `-machine mps2-an500 -cpu cortex-m7`): the
//! default scenario's plant, sensors and controller (with its EKF bank), the same library code
//! and the same `run_experiment_report` as `exompc simulate`, streaming to the host over
//! semihosting one line per record (docs/EMBEDDED.md; `firmware/qemu` splits them):
//!
//! - `I,key=value ...` the run's settings, the timer calibration and the memory figures,
//! - `H,<columns>` and `T,<row>` the trace in `exompc simulate`'s `trace.csv` format,
//! - `C,<step>,<solver>,<ekf_bank>` the cost of each control step in clock nanoseconds (with
//!   QEMU's `-icount shift=0` one nanosecond is one executed instruction),
//! - `S,<json>` the summary (`simulate`'s `summary.json`), `E,<message>` an error.
//!
//! Arguments come from the semihosting command line: `controller=msnmpc|nmpc payload=KG
//! duration=S [mode=closed-loop|serial key=KEY nonce=HEX]`.
//!
//! With `mode=serial` the firmware is the controller only (the `exompc run` of the MCU): it
//! opens an authenticated session (`exompc::runtime`'s frames, keys and handshake, the same
//! code as the host's) over the board's UART0 with `exompc virtual-robot --serial` on the
//! host, answers each of the robot's samples with a torque command, and streams only the cost
//! (`C`) and info (`I`) lines; the robot writes the trace. `key` is the pre-shared key file's
//! text, `nonce` the handshake nonce as 64 hex digits (QEMU's board has no random source: the
//! host draws it; a real board takes it from its TRNG).

#![no_std]
#![no_main]

extern crate alloc;

use alloc::format;
use alloc::string::String;
#[cfg(not(feature = "controller-only"))]
use alloc::vec::Vec;
use core::alloc::{GlobalAlloc, Layout};
use core::fmt::Write as _;
use core::sync::atomic::{AtomicU32, AtomicUsize, Ordering};
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hio, nr};
use embedded_alloc::LlffHeap;
use exompc::config::{ControllerKind, Experiment};
use exompc::control::Supervisor;
use exompc::control::{Controller, Measurement};
use exompc::estimate::MovingAverage;
use exompc::runtime::frame::{
    command_flags, max_frame_len, robot_flags, status_code, RobotCommand,
};
use exompc::runtime::{ControllerLink, Deframer, LinkStats, Psk};
use exompc::scenario::{limits, RunError, TwoDof};
#[cfg(not(feature = "controller-only"))]
use exompc::scenario::{multistage, run_experiment_report};
#[cfg(not(feature = "controller-only"))]
use exompc::sim::{RecordResult, Recorder, StepRecord};
use nalgebra::SVector;

/// Heap arena (a static array; the heap's peak use is measured).
const HEAP_BYTES: usize = 1 << 20;
/// Painted into the free RAM below the stack at start; the lowest overwritten word is the
/// stack's peak.
const PAINT: u32 = 0xDEAD_BEEF;
/// CMSDK APB timer 0 of the mps2-an500: a 32-bit down-counter on the 25 MHz system clock.
const TIMER0: usize = 0x4000_0000;
/// Nanoseconds per timer tick (25 MHz).
const NS_PER_TICK: u64 = 40;

/// The allocator with its peak use.
struct PeakHeap {
    heap: LlffHeap,
    peak: AtomicUsize,
}

unsafe impl GlobalAlloc for PeakHeap {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        let p = unsafe { self.heap.alloc(layout) };
        self.peak.fetch_max(self.heap.used(), Ordering::Relaxed);
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded with the caller's guarantees.
        unsafe { self.heap.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static HEAP: PeakHeap = PeakHeap {
    heap: LlffHeap::empty(),
    peak: AtomicUsize::new(0),
};

static mut HEAP_MEM: [u8; HEAP_BYTES] = [0; HEAP_BYTES];

/// CMSDK APB UART0 of the mps2-an500 (DATA 0x0, STATE 0x4, CTRL 0x8, BAUDDIV 0x10).
const UART0: usize = 0x4000_4000;

fn uart_reg(offset: usize) -> *mut u32 {
    (UART0 + offset) as *mut u32
}

fn uart_init() {
    // SAFETY: the UART's registers on this board; TX and RX enabled, the smallest divider.
    unsafe {
        uart_reg(0x10).write_volatile(16);
        uart_reg(0x8).write_volatile(0b11);
    }
}

fn uart_send(bytes: &[u8]) {
    for &b in bytes {
        // SAFETY: polling STATE.TXFULL (bit 0), then writing DATA.
        unsafe {
            while uart_reg(0x4).read_volatile() & 1 != 0 {}
            uart_reg(0x0).write_volatile(u32::from(b));
        }
    }
}

fn uart_recv() -> u8 {
    // SAFETY: polling STATE.RXFULL (bit 1), then reading DATA.
    unsafe {
        while uart_reg(0x4).read_volatile() & 2 == 0 {}
        uart_reg(0x0).read_volatile() as u8
    }
}

fn timer_reg(offset: usize) -> *mut u32 {
    (TIMER0 + offset) as *mut u32
}

fn timer_start() {
    // SAFETY: the CMSDK timer's registers (CTRL 0x0, VALUE 0x4, RELOAD 0x8) on this board.
    unsafe {
        timer_reg(0x8).write_volatile(u32::MAX);
        timer_reg(0x4).write_volatile(u32::MAX);
        timer_reg(0x0).write_volatile(1);
    }
}

static LAST: AtomicU32 = AtomicU32::new(0);
static WRAPS: AtomicU32 = AtomicU32::new(0);

/// Timer ticks since start, extended to 64 bits (called far more often than every 171 s).
fn ticks() -> u64 {
    // SAFETY: reading the running timer's VALUE register.
    let up = !unsafe { timer_reg(0x4).read_volatile() };
    if up < LAST.swap(up, Ordering::Relaxed) {
        WRAPS.fetch_add(1, Ordering::Relaxed);
    }
    (u64::from(WRAPS.load(Ordering::Relaxed)) << 32) | u64::from(up)
}

/// The library's clock: timer nanoseconds.
fn now_ns() -> u64 {
    ticks() * NS_PER_TICK
}

/// Writes `s` to the host's stdout in one semihosting call.
fn out(s: &str) {
    if let Ok(mut o) = hio::hstdout() {
        let _ = o.write_all(s.as_bytes());
    }
}

fn fail(msg: &str) -> ! {
    out(&format!("E,{msg}\n"));
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    let mut s = String::new();
    let _ = writeln!(s, "E,panic: {info}");
    out(&s);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

/// The semihosting command line (`SYS_GET_CMDLINE`).
fn command_line(buf: &mut [u8; 512]) -> &str {
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: GET_CMDLINE writes at most `len` bytes into `buf` and the length into `block`.
    let r = unsafe { cortex_m_semihosting::syscall1(nr::GET_CMDLINE, block.as_mut_ptr() as usize) };
    if r != 0 {
        return "";
    }
    let n = block[1].min(buf.len());
    core::str::from_utf8(&buf[..n]).unwrap_or("")
}

#[cfg(not(feature = "controller-only"))]
/// `exompc simulate`'s trace row (the library's `sim::trace::csv_row`), `T,`-prefixed, and the
/// step's cost line.
struct Stream {
    scenarios: usize,
    line: String,
}

#[cfg(not(feature = "controller-only"))]
impl Recorder<2> for Stream {
    fn record(&mut self, r: &StepRecord<'_, 2>) -> RecordResult {
        let (solver_ns, ekf_ns) = exompc::clock::take_parts();
        let l = &mut self.line;
        l.clear();
        l.push_str("T,");
        exompc::sim::trace::csv_row(r, self.scenarios, l);
        let step_ns = (r.step_time_us * 1e3 + 0.5) as u64;
        let _ = writeln!(l, "C,{step_ns},{solver_ns},{ekf_ns}");
        out(l);
        Ok(())
    }
}

#[cfg(not(feature = "controller-only"))]
/// `exompc simulate`'s trace header (the library's `sim::trace::csv_header`) for 2 joints and
/// `keys` scenarios.
fn header(keys: &[String]) -> String {
    format!("H,{}\n", exompc::sim::trace::csv_header(2, keys).join(","))
}

/// Instructions of a loop of known length per timer tick: `n` rounds of `subs` + `bne`.
fn calibrate(n: u32) -> u64 {
    let t0 = ticks();
    // SAFETY: a register-only countdown loop.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {0}, {0}, #1",
            "bne 2b",
            inout(reg) n => _,
            options(nomem, nostack),
        );
    }
    ticks() - t0
}

extern "C" {
    static __sdata: u32;
    static __edata: u32;
    static __sidata: u32;
    static __sbss: u32;
    static __ebss: u32;
    static __sheap: u32;
    static _stack_start: u32;
}

fn addr(s: &u32) -> usize {
    s as *const u32 as usize
}

/// The supervised controller of the image: any registered one (the full image), or the one
/// controller the controller-only image holds.
type Ctrl = Supervisor<2, alloc::boxed::Box<dyn Controller<2>>>;

#[cfg(not(feature = "controller-only"))]
fn build(s: &Experiment) -> Result<Ctrl, RunError> {
    exompc::scenario::build_supervised::<TwoDof, 2>(s, s.controller.kind)
}

#[cfg(feature = "controller-only")]
fn build(s: &Experiment) -> Result<Ctrl, RunError> {
    use exompc::scenario::initial_torque;
    #[cfg(feature = "serial-msnmpc")]
    let (kind, builder) = (
        ControllerKind::MSNMPC,
        exompc::scenario::build_multistage::<TwoDof, 2, 6, 4>,
    );
    #[cfg(all(feature = "serial-nmpc", not(feature = "serial-msnmpc")))]
    let (kind, builder) = (
        ControllerKind::NMPC,
        exompc::scenario::build_nmpc::<TwoDof, 2>,
    );
    if s.controller.kind != kind {
        fail(&format!(
            "controller={}: this controller-only image holds {kind}",
            s.controller.kind
        ));
    }
    let inner = builder(s, initial_torque::<TwoDof, 2>(s))?;
    Ok(supervised(s, inner))
}

/// The supervisor around the built controller, in a frame of its own: inlined into `build`,
/// its locals would sit under the builder's for the whole construction (the image's stack
/// peak, docs/EMBEDDED.md).
#[cfg(feature = "controller-only")]
#[inline(never)]
fn supervised(s: &Experiment, inner: alloc::boxed::Box<dyn Controller<2>>) -> Ctrl {
    exompc::scenario::supervise::<TwoDof, 2>(s, inner)
}

fn hex32(text: &str) -> Option<[u8; 32]> {
    let t = text.as_bytes();
    if t.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (o, pair) in out.iter_mut().zip(t.chunks(2)) {
        let s = core::str::from_utf8(pair).ok()?;
        *o = u8::from_str_radix(s, 16).ok()?;
    }
    Some(out)
}

fn link_line(name: &str, l: &LinkStats, skipped: u64) -> String {
    let r = &l.rejected;
    format!(
        "I,{name}_received={} {name}_accepted={} {name}_gaps={} {name}_rejected={} \
         {name}_rejected_bad_mac={} {name}_rejected_duplicate={} {name}_rejected_out_of_order={} \
         {name}_sent={} {name}_stream_skipped_bytes={skipped}\n",
        l.received,
        l.accepted,
        l.gaps,
        r.total(),
        r.bad_mac,
        r.duplicate,
        r.out_of_order,
        l.sent,
    )
}

/// The controller alone over the UART (`mode=serial`): handshake, then per robot sample the
/// per-sample part of `exompc run`'s loop (`runtime::ControlLoop::period` without its
/// deadlines: the link runs in lockstep with the robot's simulated time): resume from the
/// applied torque, filter velocity and force, step the supervised controller, send the
/// command answering the sample. Ends at the robot's end-of-run sample.
fn serial(s: &Experiment, key: &str, nonce: [u8; 32]) -> LinkStats {
    let psk = match Psk::new(key.as_bytes()) {
        Ok(p) => p,
        Err(e) => fail(&format!("key: {e}")),
    };
    let max_ahead = (1.0 / s.timing.dt).clamp(2.0, 1e6) as u32 + 1;
    let mut link = ControllerLink::<2>::new(psk, max_ahead);
    let mut deframer = Deframer::new(max_frame_len(2));
    let mut sup = match build(s) {
        Ok(c) => c,
        Err(e) => fail(&format!("{e}")),
    };
    let lim = limits(s);
    let mut vel = MovingAverage::<2>::new(s.uncertainty.filter_window);
    let mut force = MovingAverage::<2>::new(s.uncertainty.filter_window);
    uart_init();
    link.start(nonce);
    uart_send(link.hello(now_ns()));
    link.count_sent(true);
    // The robot's challenge establishes the session key; the first command confirms it.
    while !link.established() {
        if let Some(f) = deframer.push(uart_recv()) {
            let _ = link.receive(f);
        }
    }
    let confirm = RobotCommand::new(0, now_ns(), 0, command_flags::HELLO, SVector::zeros());
    uart_send(link.command(&confirm));
    link.count_sent(true);
    let mut started = false;
    let mut resyncs = 0u64;
    let _ = exompc::clock::take_parts();
    let mut line = String::with_capacity(64);
    loop {
        let Some(f) = deframer.push(uart_recv()) else {
            continue;
        };
        let Some(sample) = link.receive(f) else {
            continue;
        };
        if sample.flags & robot_flags::END_OF_RUN != 0 {
            break;
        }
        let applied = lim.admissible(&sample.effort);
        if started && applied != sup.previous_torque() {
            sup.set_previous_torque(applied);
            resyncs += 1;
        }
        started = true;
        let meas = Measurement {
            t: sample.stamp_ns as f64 * 1e-9,
            q: sample.q,
            qd: vel.push(sample.qd),
            force: force.push(sample.force),
        };
        let t0 = now_ns();
        let o = sup.step(&meas);
        let step_ns = now_ns() - t0;
        let (solver_ns, ekf_ns) = exompc::clock::take_parts();
        let cmd = RobotCommand {
            status: status_code(o.status),
            iterations: o.iterations,
            compute_ns: step_ns.min(u64::from(u32::MAX)) as u32,
            ..RobotCommand::new(0, now_ns(), sample.seq, 0, o.torque)
        };
        uart_send(link.command(&cmd));
        link.count_sent(true);
        line.clear();
        let _ = writeln!(line, "C,{step_ns},{solver_ns},{ekf_ns}");
        out(&line);
    }
    out(&format!("I,effort_resyncs={resyncs}\n"));
    out(&link_line("link", &link.stats(), deframer.skipped()));
    link.stats()
}

#[entry]
fn main() -> ! {
    // Paint the free RAM between the statics and the current stack.
    let sp = cortex_m::register::msp::read() as usize;
    // SAFETY: linker symbols; the painted words lie between the end of the statics and 256
    // bytes below the current stack pointer, memory nothing else uses.
    let (ram_start, ram_free, stack_top) =
        unsafe { (addr(&__sdata), addr(&__sheap), addr(&_stack_start)) };
    let mut p = ram_free;
    while p + 4 <= sp - 256 {
        // SAFETY: see above.
        unsafe { (p as *mut u32).write_volatile(PAINT) };
        p += 4;
    }
    // SAFETY: the arena is used by the allocator only, initialised once here.
    unsafe {
        HEAP.heap
            .init(core::ptr::addr_of_mut!(HEAP_MEM) as usize, HEAP_BYTES)
    }
    timer_start();
    let rounds = 1_000_000;
    let calib_ticks = calibrate(rounds);

    let mut buf = [0u8; 512];
    let args = command_line(&mut buf);
    let mut s = Experiment::default();
    let mut serial_mode = false;
    let mut key = "";
    let mut nonce = None;
    for a in args.split_whitespace() {
        match a.split_once('=') {
            Some(("controller", v)) => match v.parse::<ControllerKind>() {
                Ok(k) => s.controller.kind = k,
                Err(_) => fail(&format!("controller={v}: allowed msnmpc, nmpc, pd")),
            },
            Some(("payload", v)) => match v.parse::<f64>() {
                Ok(p) => s.uncertainty.payload_kg = p,
                Err(_) => fail(&format!("payload={v}: not a number (kg)")),
            },
            Some(("duration", v)) => match v.parse::<f64>() {
                Ok(d) => s.timing.duration_2dof_s = d,
                Err(_) => fail(&format!("duration={v}: not a number (s)")),
            },
            Some(("mode", "serial")) => serial_mode = true,
            Some(("mode", "closed-loop")) => serial_mode = false,
            Some(("mode", v)) => fail(&format!("mode={v}: allowed closed-loop, serial")),
            Some(("key", v)) => key = v,
            Some(("nonce", v)) => match hex32(v) {
                Some(n) => nonce = Some(n),
                None => fail("nonce: expected 64 hex digits"),
            },
            _ => {}
        }
    }
    if let Err(e) = s.validate() {
        fail(&format!("{e}"));
    }
    out(&format!(
        "I,controller={} payload_kg={} duration_s={} calibration_rounds={rounds} \
         calibration_instructions={} calibration_ticks={calib_ticks}\n",
        s.controller.kind,
        s.uncertainty.payload_kg,
        s.timing.duration_2dof_s,
        2 * rounds
    ));
    // The heap the controller alone holds (supervised, as the run builds it; it allocates
    // nothing per step): built, measured and dropped before the run.
    let before = HEAP.heap.used();
    let controller_heap = match build(&s) {
        Ok(c) => {
            let used = HEAP.heap.used() - before;
            drop(c);
            used
        }
        Err(e) => fail(&format!("{e}")),
    };
    out(&format!("I,controller_heap_bytes={controller_heap}\n"));

    exompc::clock::set_clock(now_ns);
    if serial_mode {
        let Some(nonce) = nonce else {
            fail("mode=serial needs nonce=<64 hex digits>")
        };
        serial(&s, key, nonce);
    } else {
        #[cfg(not(feature = "controller-only"))]
        closed_loop(&s);
        #[cfg(feature = "controller-only")]
        fail("this is the controller-only image: mode=serial only");
    }
    memory_report(ram_free, sp, stack_top, ram_start);
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}

/// The closed loop on the MCU (`mode=closed-loop`): plant, sensors and controller, streaming
/// the trace and the summary.
#[cfg(not(feature = "controller-only"))]
fn closed_loop(s: &Experiment) {
    let keys: Vec<String> = match exompc::scenario::controller_info(s.controller.kind) {
        Ok(info) if info.multistage => (1..=multistage::count(s)).map(|i| format!("{i}")).collect(),
        Ok(_) => Vec::new(),
        Err(e) => fail(&format!("{e}")),
    };
    out(&header(&keys));
    let _ = exompc::clock::take_parts();
    let mut stream = Stream {
        scenarios: keys.len(),
        line: String::with_capacity(1024),
    };
    let (summary, _report) = match run_experiment_report::<TwoDof, 2>(s, &mut [&mut stream]) {
        Ok(r) => r,
        Err(e) => fail(&format!("{e}")),
    };
    match serde_json::to_string(&summary) {
        Ok(j) => out(&format!("S,{j}\n")),
        Err(e) => fail(&format!("summary: {e}")),
    }
}

/// Memory: the statics (less the heap arena), the heap's peak, the stack's peak.
fn memory_report(ram_free: usize, sp: usize, stack_top: usize, ram_start: usize) {
    // SAFETY: linker symbols.
    let (data, bss, flash_end) = unsafe {
        (
            addr(&__edata) - addr(&__sdata),
            addr(&__ebss) - addr(&__sbss),
            addr(&__sidata) + (addr(&__edata) - addr(&__sdata)),
        )
    };
    let mut low = ram_free;
    // SAFETY: reading the painted region.
    while low < sp - 256 && unsafe { (low as *const u32).read_volatile() } == PAINT {
        low += 4;
    }
    out(&format!(
        "I,flash_bytes={flash_end} static_bytes={} heap_arena_bytes={HEAP_BYTES} \
         heap_peak_bytes={} stack_peak_bytes={} ram_start={ram_start:#x}\n",
        data + bss - HEAP_BYTES,
        HEAP.peak.load(Ordering::Relaxed),
        stack_top - low,
    ));
}
