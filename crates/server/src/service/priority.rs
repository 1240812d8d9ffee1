//! The network threads yield the CPU to the compute threads.
//!
//! Under overload both want every core: the tokio threads to read, refuse and answer
//! requests, the compute threads to run the admitted ones. At equal priority the
//! kernel splits the CPU evenly between them, and at 3× saturation the refusals took a
//! quarter of a core, so fewer of the admitted requests were answered than in a closed loop
//! (0.82× the saturation throughput, server on one core, `docs/HARDENING.md`). With the
//! network threads a few nice levels lower, a refusal waits a little longer for the CPU
//! but the answered work keeps it: 0.95× at 3×, with the same p99. When the compute
//! threads are idle, priority changes nothing. Lowering priority needs no privilege
//! (raising the compute threads' would).

/// How much lower than the process the network threads run by default, in nice levels.
pub const DEFAULT_NETWORK_NICE: i32 = 10;

/// Lowers the calling thread's priority by `levels` nice levels below the process's (at most
/// to 19, the lowest). Linux gives each thread its own nice value; elsewhere this does
/// nothing and says so.
pub fn lower_this_thread(levels: i32) -> std::io::Result<()> {
    if levels == 0 {
        return Ok(());
    }
    imp::lower_this_thread(levels)
}

#[cfg(target_os = "linux")]
mod imp {
    pub fn lower_this_thread(levels: i32) -> std::io::Result<()> {
        // SAFETY: plain system calls on this thread's own id; no memory is shared.
        unsafe {
            let tid = libc::gettid() as libc::id_t;
            // getpriority may legitimately return -1: errno tells an error apart.
            *libc::__errno_location() = 0;
            let current = libc::getpriority(libc::PRIO_PROCESS, tid);
            if current == -1 && *libc::__errno_location() != 0 {
                return Err(std::io::Error::last_os_error());
            }
            let target = (current + levels).clamp(-20, 19);
            if libc::setpriority(libc::PRIO_PROCESS, tid, target) != 0 {
                return Err(std::io::Error::last_os_error());
            }
        }
        Ok(())
    }
}

#[cfg(not(target_os = "linux"))]
mod imp {
    pub fn lower_this_thread(_levels: i32) -> std::io::Result<()> {
        Err(std::io::Error::new(
            std::io::ErrorKind::Unsupported,
            "per-thread priority is Linux only",
        ))
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    fn nice_of_this_thread() -> i32 {
        // SAFETY: as above.
        unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t) }
    }

    #[test]
    fn lowers_only_the_calling_thread() {
        let process = nice_of_this_thread();
        let lowered = std::thread::spawn(|| {
            lower_this_thread(3).unwrap();
            nice_of_this_thread()
        })
        .join()
        .unwrap();
        assert_eq!(lowered, (process + 3).min(19));
        assert_eq!(nice_of_this_thread(), process);
        let clamped = std::thread::spawn(|| {
            lower_this_thread(100).unwrap();
            nice_of_this_thread()
        })
        .join()
        .unwrap();
        assert_eq!(clamped, 19);
    }
}
