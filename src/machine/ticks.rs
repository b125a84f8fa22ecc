//! The nodes' stopwatch: host time for the emulation's bookkeeping (how
//! long a unit of work took, when a slice or a CPU-time window ends), read
//! a million times a second per node. Owns nothing but a process-wide
//! calibration; touches no other module.
//!
//! `std::time::Instant` costs about 25 ns a reading on this host's virtual
//! machine (the vDSO's clock_gettime), which made clock reads 3% of a
//! `--dim 1` render's CPU and 5% of a `--dim 5` one's (`perf`). The
//! processor's time-stamp counter costs about 10 ns. It is used where the
//! kernel itself keeps time by it (the clock source is `tsc`, which Linux
//! picks only for a counter that is invariant and in step across CPUs), its
//! rate measured once against `Instant`; elsewhere `Instant` stands in.
//! Only differences between readings are ever used, and they saturate at
//! zero, so a reading taken on another core a little behind can never make
//! time run backwards.
//!
//! Also here: the kernel's CPU clocks of the thread (what a node computed,
//! read once a window) and of the process (how many cores a run had).

use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// A reading of the stopwatch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Ticks(u64);

/// What a tick is on this host.
#[derive(Debug)]
struct Source {
    /// Whether ticks are the time-stamp counter's (else nanoseconds since
    /// `epoch`).
    tsc: bool,
    seconds_per_tick: f64,
    epoch: Instant,
}

static SOURCE: OnceLock<Source> = OnceLock::new();

/// How long the counter's rate is measured against `Instant`: each end is
/// held to some 25 ns (`bracketed`), so the rate is known to a few parts
/// in 100,000, far below the noise of what the nodes time.
const CALIBRATION: Duration = Duration::from_millis(2);

/// Decides the source and measures its rate, once per process. Called by
/// the host before the node threads start, so that no node's first slice
/// pays for it; any first reading would do it too.
pub fn calibrate() {
    source();
}

fn source() -> &'static Source {
    SOURCE.get_or_init(|| {
        let epoch = Instant::now();
        let instant = Source {
            tsc: false,
            seconds_per_tick: 1e-9,
            epoch,
        };
        if !kernel_keeps_time_by_tsc() {
            return instant;
        }
        let Some((i0, c0)) = bracketed() else {
            return instant;
        };
        while i0.elapsed() < CALIBRATION {
            std::hint::spin_loop();
        }
        let Some((i1, c1)) = bracketed() else {
            return instant;
        };
        let seconds = (i1 - i0).as_secs_f64();
        let rate = c1.checked_sub(c0).map(|n| n as f64 / seconds);
        match rate {
            // A counter from 100 MHz to 100 GHz; anything else is not
            // the clock it was taken for.
            Some(hz) if (1e8..1e11).contains(&hz) => Source {
                tsc: true,
                seconds_per_tick: 1.0 / hz,
                epoch,
            },
            _ => instant,
        }
    })
}

/// An `Instant` and the counter at the same moment: the counter read just
/// before and just after it, their middle, from the tightest of some
/// tries. A thread descheduled between the two readings of a single try
/// would put the counter off by its whole wait (a shared host's
/// milliseconds, against a calibration of two): the tightest of sixteen
/// holds the moment to a few tens of nanoseconds unless every try waited.
fn bracketed() -> Option<(Instant, u64)> {
    (0..16)
        .filter_map(|_| {
            let before = counter();
            let at = Instant::now();
            let after = counter();
            let spread = after.checked_sub(before)?;
            Some((spread, at, before + spread / 2))
        })
        .min_by_key(|&(spread, _, _)| spread)
        .map(|(_, at, c)| (at, c))
}

/// Whether Linux keeps its own time by the time-stamp counter: it does so
/// only after checking that the counter runs at a constant rate, through
/// sleep states, and in step on every CPU.
fn kernel_keeps_time_by_tsc() -> bool {
    cfg!(target_arch = "x86_64")
        && std::fs::read_to_string(
            "/sys/devices/system/clocksource/clocksource0/current_clocksource",
        )
        .is_ok_and(|s| s.trim() == "tsc")
}

/// The raw counter (0 where there is none; never read then).
#[inline(always)]
fn counter() -> u64 {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: `rdtsc` exists on every x86-64 processor and only reads
        // the counter.
        unsafe { core::arch::x86_64::_rdtsc() }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        0
    }
}

impl Ticks {
    /// The stopwatch now.
    #[inline(always)]
    pub fn now() -> Ticks {
        let s = source();
        if s.tsc {
            Ticks(counter())
        } else {
            Ticks(s.epoch.elapsed().as_nanos() as u64)
        }
    }

    /// Seconds from `earlier` to `self`; zero if `earlier` is not before.
    #[inline(always)]
    pub fn seconds_since(self, earlier: Ticks) -> f64 {
        self.0.saturating_sub(earlier.0) as f64 * source().seconds_per_tick
    }

    /// Seconds from `self` to now.
    #[inline(always)]
    pub fn elapsed(self) -> f64 {
        Ticks::now().seconds_since(self)
    }
}

/// Thread CPU time in seconds: what the calling thread computed, not what
/// the host's scheduler gave other threads meanwhile. A system call (about
/// 0.5 µs here), so the nodes read it once a window, not per unit.
pub fn thread_cpu_seconds() -> f64 {
    cpu_clock(libc::CLOCK_THREAD_CPUTIME_ID)
}

/// CPU seconds of the whole process so far (every thread): beside a run's
/// wall time, how many cores it really had.
pub fn process_cpu_seconds() -> f64 {
    cpu_clock(libc::CLOCK_PROCESS_CPUTIME_ID)
}

/// Reads one of the kernel's CPU clocks; 0 where it is unavailable (never
/// on Linux), so that a reading can only understate work.
fn cpu_clock(clock: libc::clockid_t) -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec, which we own.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    if rc != 0 {
        return 0.0;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_earlier_reading_taken_later_gives_no_time_not_negative_time() {
        // As a reading on a core whose counter is a little behind would.
        assert_eq!(Ticks(1_000).seconds_since(Ticks(1_005)), 0.0);
        assert!(Ticks(1_005).seconds_since(Ticks(1_000)) > 0.0);
    }

    #[test]
    fn a_sleep_takes_at_least_its_length_in_ticks() {
        // A lower bound only: the sleep may take longer on a loaded host,
        // never shorter, whichever source this host uses.
        let t = Ticks::now();
        std::thread::sleep(Duration::from_millis(20));
        let s = t.elapsed();
        assert!(s >= 0.019, "20 ms slept, {s} s measured");
        // Bracketed by `Instant` readings: the ticks' interval lies within
        // theirs, so it can be no longer (a descheduling between readings
        // only widens the outer one), and holds the whole sleep.
        let i0 = Instant::now();
        let t = Ticks::now();
        std::thread::sleep(Duration::from_millis(5));
        let by_ticks = t.elapsed();
        let by_instant = i0.elapsed().as_secs_f64();
        assert!(by_ticks >= 0.00499, "5 ms slept, {by_ticks} s measured");
        assert!(
            by_ticks <= by_instant * 1.001 + 1e-6,
            "ticks {by_ticks} s within Instant's {by_instant} s"
        );
    }
}
