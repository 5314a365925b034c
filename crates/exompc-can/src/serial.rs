//! File-descriptor ports for slcan on Unix: a serial device (a CANable's `/dev/ttyACM0`) in raw
//! mode, and a pseudo-terminal pair so that a virtual adapter can sit behind a device path.

use crate::slcan::Port;
use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::os::fd::{AsRawFd, RawFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Wait until `fd` is ready for `events` (`POLLIN`/`POLLOUT`) or `timeout` passes; `true` when
/// ready.
fn wait_fd(fd: RawFd, events: libc::c_short, timeout: Duration) -> std::io::Result<bool> {
    let mut pfd = libc::pollfd {
        fd,
        events,
        revents: 0,
    };
    #[cfg(target_os = "linux")]
    let r = {
        let ts = libc::timespec {
            tv_sec: timeout.as_secs().min(i32::MAX as u64) as libc::time_t,
            tv_nsec: timeout.subsec_nanos() as libc::c_long,
        };
        // SAFETY: one valid pollfd, a valid timespec, no signal mask.
        unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) }
    };
    #[cfg(not(target_os = "linux"))]
    let r = {
        let ms = timeout.as_micros().div_ceil(1000).min(i32::MAX as u128) as libc::c_int;
        // SAFETY: one valid pollfd.
        unsafe { libc::poll(&mut pfd, 1, ms) }
    };
    if r < 0 {
        let e = std::io::Error::last_os_error();
        if e.kind() == std::io::ErrorKind::Interrupted {
            return Ok(false);
        }
        return Err(e);
    }
    Ok(r > 0)
}

fn set_nonblocking(fd: RawFd) -> std::io::Result<()> {
    // SAFETY: fcntl on an fd we own.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Put a terminal into raw mode: no echo, no line editing, no `\r`/`\n` translation, 8 bit.
fn set_raw(fd: RawFd) -> std::io::Result<()> {
    // SAFETY: termios is plain data; tcgetattr fills it.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    // SAFETY: valid fd and pointer.
    if unsafe { libc::tcgetattr(fd, &mut t) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: valid pointer.
    unsafe { libc::cfmakeraw(&mut t) };
    t.c_cflag |= libc::CLOCAL | libc::CREAD;
    t.c_cc[libc::VMIN] = 0;
    t.c_cc[libc::VTIME] = 0;
    // SAFETY: valid fd and pointer.
    if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// A byte stream over a file descriptor (non-blocking, waits by `poll`).
pub struct FdPort {
    file: File,
}

impl FdPort {
    /// Open a serial device (e.g. `/dev/ttyACM0`) or a pty's device path, in raw mode when it
    /// is a terminal. USB CDC adapters (CANable) ignore the serial baud rate.
    pub fn open(path: &Path) -> std::io::Result<Self> {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
            .open(path)?;
        // SAFETY: isatty on a valid fd.
        if unsafe { libc::isatty(file.as_raw_fd()) } == 1 {
            set_raw(file.as_raw_fd())?;
        }
        Ok(FdPort { file })
    }

    /// A port over an open file (made non-blocking).
    pub fn from_file(file: File) -> std::io::Result<Self> {
        set_nonblocking(file.as_raw_fd())?;
        Ok(FdPort { file })
    }
}

impl Port for FdPort {
    fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        if !wait_fd(self.file.as_raw_fd(), libc::POLLIN, timeout)? {
            return Ok(0);
        }
        match self.file.read(buf) {
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted
                ) =>
            {
                Ok(0)
            }
            // A pty master reads EIO while no one holds the device side open.
            Err(e) if e.raw_os_error() == Some(libc::EIO) => {
                std::thread::sleep(timeout.min(Duration::from_millis(1)));
                Ok(0)
            }
            Err(e) => Err(e),
        }
    }

    fn write_all_timeout(&mut self, mut bytes: &[u8], timeout: Duration) -> std::io::Result<()> {
        let end = Instant::now() + timeout;
        while !bytes.is_empty() {
            match self.file.write(bytes) {
                Ok(0) => return Err(std::io::ErrorKind::WriteZero.into()),
                Ok(n) => bytes = &bytes[n..],
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    let left = end.saturating_duration_since(Instant::now());
                    if left.is_zero() || !wait_fd(self.file.as_raw_fd(), libc::POLLOUT, left)? {
                        return Err(std::io::ErrorKind::TimedOut.into());
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}

/// A pseudo-terminal: the master end for a virtual adapter, the device path for the host
/// (which opens it like a serial port). The device side is kept open and in raw mode.
pub struct Pty {
    master: File,
    _device: File,
    path: PathBuf,
}

impl Pty {
    /// A new pseudo-terminal pair.
    pub fn open() -> std::io::Result<Self> {
        // SAFETY: plain libc calls on the fd they return; ptsname's static buffer is copied at
        // once (under a lock, as it is not thread-safe).
        unsafe {
            let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY);
            if fd < 0 {
                return Err(std::io::Error::last_os_error());
            }
            let master = <File as std::os::fd::FromRawFd>::from_raw_fd(fd);
            if libc::grantpt(fd) < 0 || libc::unlockpt(fd) < 0 {
                return Err(std::io::Error::last_os_error());
            }
            static PTSNAME: std::sync::Mutex<()> = std::sync::Mutex::new(());
            let path = {
                let _g = PTSNAME.lock().unwrap_or_else(|e| e.into_inner());
                let p = libc::ptsname(fd);
                if p.is_null() {
                    return Err(std::io::Error::last_os_error());
                }
                let s = std::ffi::CStr::from_ptr(p).to_string_lossy().into_owned();
                PathBuf::from(s)
            };
            let device = OpenOptions::new()
                .read(true)
                .write(true)
                .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
                .open(&path)?;
            set_raw(device.as_raw_fd())?;
            set_nonblocking(fd)?;
            Ok(Pty {
                master,
                _device: device,
                path,
            })
        }
    }

    /// The device path the host opens (e.g. `/dev/pts/3`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The master end as a [`Port`] (for [`SlcanAdapter`](crate::slcan_adapter::SlcanAdapter)).
    pub fn master(&self) -> std::io::Result<FdPort> {
        Ok(FdPort {
            file: self.master.try_clone()?,
        })
    }
}
