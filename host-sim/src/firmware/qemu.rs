//! The firmware in QEMU: building the ELF, booting it in QEMU mps2-an386 with its UARTs on
//! Unix sockets, feeding it the link (and in the robot loop the lidar's line), and reading its
//! map stream back.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context};
use ogm_field::stream::{DeviceEvent, StreamDecoder};

use super::robot::Line;

/// Boots `elf` in QEMU with UART1 (the link) on a Unix socket, sends `input`, returns the
/// stream bytes, the exit status, the wall time and what the firmware wrote to the lidar. With
/// `lidar`, UART0 is a second socket that carries its bytes, written by their own thread at
/// their own pace (after the request the sensor answers, if it waits for one).
pub(super) fn run_qemu(
    elf: &Path,
    input: &[u8],
    lidar: Option<LidarLine<'_>>,
    timeout: Duration,
    log: Option<&Path>,
) -> anyhow::Result<QemuRun> {
    let (steps, lidar_bytes, answers) = match &lidar {
        // The robot loop: both lines in their schedule's order, as a robot's run in step;
        // `Finish` only once the last turn is reported.
        Some(l) => {
            let mut steps: Vec<Step> = l
                .schedule
                .iter()
                .map(|(line, r)| Step {
                    line: *line,
                    bytes: r.clone(),
                    after: None,
                })
                .collect();
            steps.push(Step {
                line: Line::Link,
                bytes: input.len()..input.len() + l.finish.len(),
                after: Some(l.last_turn),
            });
            (steps, Some(l.bytes), l.answers)
        }
        None => (
            vec![Step {
                line: Line::Link,
                bytes: 0..input.len(),
                after: None,
            }],
            None,
            None,
        ),
    };
    let link: Vec<u8> = match &lidar {
        Some(l) => [input, l.finish].concat(),
        None => input.to_vec(),
    };
    run_qemu_paced(
        elf,
        Paced {
            link: &link,
            lidar: lidar_bytes,
            steps: &steps,
            answers,
            host: None,
        },
        timeout,
        log,
    )
    .map(|(run, _)| run)
}

/// One write of a paced run: `bytes` of `line`'s input, written once the firmware has
/// reported scan or turn `after` (if given) and the host's answers to everything it streamed
/// up to that report are written to the link.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct Step {
    pub(super) line: Line,
    pub(super) bytes: std::ops::Range<usize>,
    pub(super) after: Option<u32>,
}

/// An online host: sees every event the firmware streams, in order; what it returns is sent
/// down the link after the report it was made before (at the latest before the next step
/// that waits for that report), or at once if [`Answer::now`].
pub(super) type Host<'a> = Box<dyn FnMut(&DeviceEvent) -> Answer + 'a>;

/// What an online host sends back for one event of the robot's stream.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Answer {
    /// Frames for the link.
    pub bytes: Vec<u8>,
    /// Send them (and everything answered before them) at once: the robot holds a turn until
    /// they arrive (`RunConfig::window_hold`), so no report comes first.
    pub now: bool,
}

/// What the reader hands the writer: the answers made up to report `seq`, or answers due at
/// once.
enum Due {
    Report(u32, Vec<u8>),
    Now(Vec<u8>),
}

/// A paced run's input: the link's and the lidar's bytes, the steps that write them, the
/// request the sensor waits for (an RPLIDAR's `SCAN`), and the online host.
pub(super) struct Paced<'a> {
    pub(super) link: &'a [u8],
    pub(super) lidar: Option<&'a [u8]>,
    pub(super) steps: &'a [Step],
    pub(super) answers: Option<[u8; 2]>,
    pub(super) host: Option<Host<'a>>,
}

/// [`run_qemu`] in steps (lock-step with the firmware's reports where a step says so), with
/// an online host answering the stream; also returns what the link carried, in order (the
/// input and the host's answers).
///
/// Why this is deterministic: the host's answers to report `s` are written before the step
/// that waits for `s`, so they reach the firmware before every byte after that step, whatever
/// the timing. A step that waits for scan `s` before the bytes that let the firmware map
/// scan `s + 1` (its `ScanEnd`; a robot's pose after the next turn's first packet, the only
/// thing that completes a turn) puts every answer to scan `s` before scan `s + 1` is mapped:
/// the replay of the link as sent sees them at the same place.
pub(super) fn run_qemu_paced(
    elf: &Path,
    input: Paced<'_>,
    timeout: Duration,
    log: Option<&Path>,
) -> anyhow::Result<(QemuRun, Vec<u8>)> {
    let root = repo_root();
    let dir = std::env::temp_dir().join(format!("ogm-fw-{}-{}", std::process::id(), rand_seed()));
    std::fs::create_dir_all(&dir)?;
    let sock = dir.join("u1.sock");
    let listener =
        UnixListener::bind(&sock).with_context(|| format!("binding {}", sock.display()))?;
    listener.set_nonblocking(true)?;
    let sock0 = dir.join("u0.sock");
    let listener0 = match &input.lidar {
        Some(_) => Some(
            UnixListener::bind(&sock0).with_context(|| format!("binding {}", sock0.display()))?,
        ),
        None => None,
    };
    let mut cmd = Command::new("bash");
    cmd.arg(root.join("scripts/firmware.sh"))
        .arg("qemu")
        .arg(elf)
        .args(["--timeout", &timeout.as_secs().max(1).to_string()])
        .args(["--uart1", "chardev:u1"]);
    if input.lidar.is_some() {
        cmd.args(["--uart0", "chardev:u0"]);
    }
    cmd.arg("--");
    if input.lidar.is_some() {
        cmd.arg("-chardev")
            .arg(format!("socket,id=u0,path={}", sock0.display()));
    }
    cmd.arg("-chardev")
        .arg(format!("socket,id=u1,path={}", sock.display()));
    cmd.stdin(Stdio::null());
    if let Some(log) = log {
        let f =
            std::fs::File::create(log).with_context(|| format!("creating {}", log.display()))?;
        cmd.stdout(Stdio::from(f.try_clone()?))
            .stderr(Stdio::from(f));
    }
    let t0 = Instant::now();
    let mut child = cmd.spawn().context("starting scripts/firmware.sh qemu")?;
    let log_tail = || log.map(|l| tail(l, 40)).unwrap_or_default();
    let mut accept = |listener: &UnixListener, path: &Path| -> anyhow::Result<UnixStream> {
        loop {
            match listener.accept() {
                Ok((s, _)) => {
                    s.set_nonblocking(false)?;
                    return Ok(s);
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if let Some(st) = child.try_wait()? {
                        let _ = std::fs::remove_dir_all(&dir);
                        bail!(
                            "QEMU exited ({st}) before connecting to {}:\n{}",
                            path.display(),
                            log_tail()
                        );
                    }
                    if t0.elapsed() > Duration::from_secs(60) {
                        let _ = child.kill();
                        let _ = std::fs::remove_dir_all(&dir);
                        bail!("QEMU did not connect to {} within 60 s", path.display());
                    }
                    std::thread::sleep(Duration::from_millis(10));
                }
                Err(e) => return Err(e.into()),
            }
        }
    };
    let stream = accept(&listener, &sock)?;
    let lidar_stream = match &listener0 {
        Some(l) => {
            l.set_nonblocking(true)?;
            Some(accept(l, &sock0)?)
        }
        None => None,
    };
    let writer = stream.try_clone()?;
    // Send only once the firmware has spoken (its Hello): its UART is initialised by then.
    // Bytes that arrive earlier can meet the init's dummy read of the data register (board
    // `Uart::new`, which QEMU needs to start delivering input) and be lost: seen once in ~20
    // noisy-link runs as a lost first frame delimiter.
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
    // Reports, each with the host's answers to the stream up to it, and answers due at once.
    let (report_tx, report_rx) = std::sync::mpsc::channel::<Due>();
    let Paced {
        link,
        lidar,
        steps,
        answers,
        mut host,
    } = input;
    let pace_wait = timeout + Duration::from_secs(10);
    let (out, status, written) = std::thread::scope(|scope| -> anyhow::Result<_> {
        // The lidar's socket is handed back, not closed, when its bytes are written: QEMU's
        // socket chardev drops a connection, and whatever of it is still unread, the moment
        // the peer hangs up; it stays open until QEMU has exited.
        let writer = scope.spawn(move || {
            let mut w = Writer {
                link: writer,
                lidar: lidar_stream,
                sent: Vec::new(),
                heard: Vec::new(),
                answers,
            };
            let r = (|| -> std::io::Result<()> {
                if ready_rx.recv().is_err() {
                    return Ok(()); // the firmware never spoke; the reader reports it
                }
                let mut reported: Option<u32> = None;
                for step in steps {
                    // Answers already made go out first (a held turn waits for them).
                    while let Ok(due) = report_rx.try_recv() {
                        w.take(due, &mut reported)?;
                    }
                    if let Some(s) = step.after {
                        while reported.is_none_or(|r| r < s) {
                            match report_rx.recv_timeout(pace_wait) {
                                Ok(due) => w.take(due, &mut reported)?,
                                // The firmware stopped reporting: the run has failed, and the
                                // reader's status says why.
                                Err(_) => return Ok(()),
                            }
                        }
                    }
                    match step.line {
                        Line::Link => w.write_link(&link[step.bytes.clone()])?,
                        Line::Lidar => w.write_lidar(&lidar.unwrap_or(&[])[step.bytes.clone()])?,
                    }
                }
                Ok(())
            })();
            (r, w)
        });
        let mut ready = Some(ready_tx);
        let mut watch = StreamDecoder::new();
        let mut answer = Vec::new();
        let mut reader = stream;
        reader.set_read_timeout(Some(Duration::from_millis(200)))?;
        let mut out = Vec::new();
        let mut buf = [0u8; 16 * 1024];
        let deadline = t0 + timeout + Duration::from_secs(10);
        let mut status = None;
        loop {
            match reader.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    out.extend_from_slice(&buf[..n]);
                    if let Some(go) = ready.take() {
                        let _ = go.send(());
                    }
                    for e in watch.push(&buf[..n]).into_iter().flatten() {
                        if let Some(h) = host.as_mut() {
                            let a = h(&e);
                            answer.extend(a.bytes);
                            if a.now {
                                let _ = report_tx.send(Due::Now(std::mem::take(&mut answer)));
                            }
                        }
                        if let DeviceEvent::Scan(r) = e {
                            let _ = report_tx.send(Due::Report(r.seq, std::mem::take(&mut answer)));
                        }
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    if let Some(st) = child.try_wait()? {
                        status = Some(st);
                        // Drain what is left.
                        reader.set_nonblocking(true)?;
                        while let Ok(n) = reader.read(&mut buf) {
                            if n == 0 {
                                break;
                            }
                            out.extend_from_slice(&buf[..n]);
                        }
                        break;
                    }
                    if Instant::now() > deadline {
                        let _ = child.kill();
                        break;
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => break,
                Err(e) => return Err(e.into()),
            }
        }
        if status.is_none() {
            let wait_until = Instant::now() + Duration::from_secs(15);
            loop {
                if let Some(st) = child.try_wait()? {
                    status = Some(st);
                    break;
                }
                if Instant::now() > wait_until {
                    let _ = child.kill();
                    status = child.wait().ok();
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        drop(ready);
        drop(report_tx);
        let written = writer.join().ok().map(|(_, w)| (w.sent, w.heard));
        Ok((out, status, written))
    })?;
    let secs = t0.elapsed().as_secs_f64();
    let (link_sent, heard) = written.unwrap_or_default();
    let _ = std::fs::remove_dir_all(&dir);
    Ok((
        QemuRun {
            stream: out,
            status,
            secs,
            heard,
        },
        link_sent,
    ))
}

/// The writing end of a paced run: both lines, what the link carried, what the firmware
/// wrote to the sensor before it answered.
struct Writer {
    link: UnixStream,
    lidar: Option<UnixStream>,
    sent: Vec<u8>,
    heard: Vec<u8>,
    answers: Option<[u8; 2]>,
}

impl Writer {
    /// Writes answers the reader handed over; a report's raises `reported`.
    fn take(&mut self, due: Due, reported: &mut Option<u32>) -> std::io::Result<()> {
        match due {
            Due::Report(seq, bytes) => {
                self.write_link(&bytes)?;
                *reported = Some(reported.map_or(seq, |r| r.max(seq)));
                Ok(())
            }
            Due::Now(bytes) => self.write_link(&bytes),
        }
    }

    fn write_link(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.sent.extend_from_slice(bytes);
        self.link.write_all(bytes)
    }

    fn write_lidar(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let Some(w) = self.lidar.as_mut() else {
            return Ok(());
        };
        if let Some(req) = self.answers.take() {
            await_request(w, req, &mut self.heard)?;
        }
        w.write_all(bytes)
    }
}

/// What [`run_qemu`] returns.
pub(super) struct QemuRun {
    /// The map stream (UART1).
    pub(super) stream: Vec<u8>,
    /// QEMU's exit status (`None`: killed at the timeout).
    pub(super) status: Option<ExitStatus>,
    /// Wall time, s.
    pub(super) secs: f64,
    /// What the firmware wrote to the lidar (UART0) before the sensor's first byte.
    pub(super) heard: Vec<u8>,
}

/// The robot loop's second serial line and its end: the lidar's bytes on UART0, the order
/// the two lines carry their bytes in, and the `Finish` frame the link sends once the firmware
/// has reported turn `last_turn`.
pub(super) struct LidarLine<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) schedule: &'a [(super::robot::Line, std::ops::Range<usize>)],
    pub(super) finish: &'a [u8],
    pub(super) last_turn: u32,
    /// The request the sensor waits for before its first byte (an RPLIDAR's `SCAN`; an LD06
    /// streams on its own).
    pub(super) answers: Option<[u8; 2]>,
}

/// How long the simulated sensor waits for the request it answers (wall time).
const REQUEST_WAIT: Duration = Duration::from_secs(30);

/// Reads `line` until `request` arrived (or `REQUEST_WAIT` passed); every byte the firmware
/// wrote to the sensor meanwhile goes to `heard`.
fn await_request(
    line: &mut UnixStream,
    request: [u8; 2],
    heard: &mut Vec<u8>,
) -> std::io::Result<()> {
    line.set_read_timeout(Some(Duration::from_millis(50)))?;
    let t0 = Instant::now();
    let mut buf = [0u8; 64];
    while !heard.windows(2).any(|w| w == request) && t0.elapsed() < REQUEST_WAIT {
        match line.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => heard.extend_from_slice(&buf[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e),
        }
    }
    line.set_read_timeout(None)
}

/// Builds the firmware with `scripts/firmware.sh build`; returns the ELF.
pub fn build_elf(log: &Path) -> anyhow::Result<PathBuf> {
    build_elf_with(log, None)
}

/// [`build_elf`] with optional firmware `features` (comma-separated; their own target dir).
pub fn build_elf_with(log: &Path, features: Option<&str>) -> anyhow::Result<PathBuf> {
    let root = repo_root();
    let log_file =
        std::fs::File::create(log).with_context(|| format!("creating {}", log.display()))?;
    let mut cmd = Command::new("bash");
    if let Some(f) = features {
        cmd.env("FIRMWARE_FEATURES", f);
    }
    let out = cmd
        .arg(root.join("scripts/firmware.sh"))
        .arg("build")
        .stdin(Stdio::null())
        .stderr(Stdio::from(log_file))
        .output()
        .context("running scripts/firmware.sh build")?;
    if !out.status.success() {
        bail!(
            "scripts/firmware.sh build failed ({}):\n{}",
            out.status,
            tail(log, 30)
        );
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let elf = stdout
        .lines()
        .last()
        .map(|l| PathBuf::from(l.trim()))
        .context("scripts/firmware.sh build printed no ELF path")?;
    ensure!(elf.exists(), "ELF {} does not exist", elf.display());
    Ok(elf)
}

fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let v: Vec<&str> = text.lines().collect();
    v[v.len().saturating_sub(lines)..].join("\n")
}

/// Checks that `path` is an ELF executable (one-line errors naming the file).
pub fn check_elf(path: &Path) -> anyhow::Result<()> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{}: file not found", path.display())
        }
        Err(e) => bail!("{}: cannot read: {e}", path.display()),
    };
    ensure!(!bytes.is_empty(), "{}: file is empty", path.display());
    ensure!(
        bytes.starts_with(b"\x7fELF"),
        "{}: wrong format: not an ELF file",
        path.display()
    );
    // 32-bit ELF header: 52 bytes; the program headers it points to must be in the file too.
    let u32_at = |o: usize| {
        bytes
            .get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let u16_at = |o: usize| {
        bytes
            .get(o..o + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
    };
    let ph_end = match (u32_at(28), u16_at(42), u16_at(44)) {
        (Some(off), Some(size), Some(n)) => off as usize + usize::from(size) * usize::from(n),
        _ => usize::MAX,
    };
    ensure!(
        bytes.len() >= 52 && bytes.len() >= ph_end,
        "{}: truncated ELF file ({} bytes)",
        path.display(),
        bytes.len()
    );
    Ok(())
}

/// The repository root (host-sim's parent directory).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

/// Why the firmware cannot run here, if it cannot: `firmware/target/toolchain.env` (written by
/// `scripts/firmware-toolchain.sh`) and the QEMU it names must exist.
pub fn toolchain_missing() -> Option<String> {
    let env = repo_root().join("firmware/target/toolchain.env");
    let Ok(text) = std::fs::read_to_string(&env) else {
        return Some(format!(
            "{} not found: run `bash scripts/firmware-toolchain.sh` first",
            env.display()
        ));
    };
    let qemu = text
        .lines()
        .find_map(|l| l.strip_prefix("FW_QEMU="))
        .unwrap_or("");
    if qemu.is_empty() || !Path::new(qemu).exists() {
        return Some(format!(
            "QEMU ({}) from {} does not exist: rerun `bash scripts/firmware-toolchain.sh`",
            if qemu.is_empty() { "unset" } else { qemu },
            env.display()
        ));
    }
    None
}

fn rand_seed() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}
