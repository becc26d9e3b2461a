//! `host-sim listen` on the firmware in QEMU, its link UART on a pseudo-terminal (issue 14):
//!
//! 1. **Equality.** The listener opens the pty, sends a short simulated run (settings, poses,
//!    LD06 packets, `Finish`: `--send` lines made from `encode_run`), decodes the map stream and
//!    saves on the robot's `Done`. Its PGM/YAML/PNG (marginals and log-odds) must be byte for
//!    byte what the same writer makes of the **host replay's** map (ogm-core on the host, fed
//!    the same input and the sampler update counts the firmware reported), and its map must
//!    equal the replay's cell for cell.
//! 2. **Kill and restart.** A listener sends the settings and scans 0–1, and is killed
//!    (abandoned without saving) as soon as scan 1's report arrived. While no listener runs, the
//!    robot keeps working: scans 2–4 go in and their map stream goes nowhere (this test reads
//!    and discards it; on a real robot the lidar and odometry do not need the host). A second
//!    listener resumes from the first one's capture, sends scans 5–7 and `Finish`, and must
//!    resynchronise and report exactly scans 2–4 as missed.
//!
//! QEMU starts paused (`-S`) with UART1 on a pseudo-terminal the test owns ([`PtyRelay`]: QEMU
//! opens the slave of one pty pair, the listener the slave of another, and the test copies
//! between their masters), and the guest runs (`cont`) once the listener has its device open,
//! so the robot's `Hello` is not lost and the host answers within the firmware's 100 ms. With
//! QEMU's own `-chardev pty` its exit closed the master, which hung up the listener's device
//! and dropped what it had not read yet: once, the robot's last frame (`Done`).
//!
//! Needs the firmware toolchain and QEMU; skipped with a message without them unless
//! `OGM_REQUIRE_FIRMWARE=1`. Runtime: a few seconds per part after the firmware build.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use host_sim::firmware::input::{encode_run, send_lines, RunInput, Unit, UnitKind};
use host_sim::firmware::{
    build_elf, firmware_world, replay_map, repo_root, run_config, sim_config, FirmwareArgs,
};
use ogm_core::config::RunConfig;
use ogm_core::wire::HostMsg;
use ogm_field::export::export_world;
use ogm_field::listen::{
    open_port, run, Control, Gap, ListenArgs, ListenStats, Listener, CAPTURE_FILE,
};
use ogm_field::stream::{
    counts_of_one, decode_file, stream_probabilities, DeviceEvent, MapLayer, StreamDecoder,
};
use ogm_field::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use ogm_field::world::probabilities_to_world;

const SCANS: usize = 8;

/// The ELF, built once for both tests.
fn elf() -> PathBuf {
    static ELF: Mutex<Option<PathBuf>> = Mutex::new(None);
    let mut e = ELF.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(p) = e.as_ref() {
        return p.clone();
    }
    let dir = repo_root().join("firmware/target/qemu");
    std::fs::create_dir_all(&dir).unwrap();
    let p = build_elf(&dir.join("listen-pty-build.log")).expect("firmware build");
    *e = Some(p.clone());
    p
}

/// A short simulated run: its settings and the robot's input.
fn simulated_run(seed: u64) -> (RunConfig, RunInput) {
    let args = FirmwareArgs {
        seed,
        max_scans: Some(SCANS),
        ..FirmwareArgs::default()
    };
    let world = firmware_world(&args).unwrap();
    let sim = host_sim::sim::simulate(&world, &sim_config(&args), seed).unwrap();
    let mut scans = sim.scans.clone();
    scans.truncate(SCANS);
    assert_eq!(scans.len(), SCANS, "the simulated run is too short");
    let config = run_config(&world, &args, sim.mapper_config.max_range_mm);
    (config, encode_run(&config, &scans, false).unwrap())
}

/// `input` cut before the `ScanStart` of each scan in `at` (and nowhere else).
fn split_before_scans(input: &RunInput, at: &[u32]) -> Vec<RunInput> {
    let mut parts = vec![RunInput::default()];
    for u in &input.units {
        let bytes = &input.bytes[u.start..u.start + u.len];
        if u.kind == UnitKind::Frame {
            let mut body = bytes[1..bytes.len() - 1].to_vec();
            if let Ok(HostMsg::ScanStart { seq, .. }) = ogm_core::wire::decode(&mut body) {
                if at.contains(&seq) {
                    parts.push(RunInput::default());
                }
            }
        }
        let p = parts.last_mut().unwrap();
        p.units.push(Unit {
            start: p.bytes.len(),
            ..*u
        });
        p.bytes.extend_from_slice(bytes);
    }
    assert_eq!(parts.len(), at.len() + 1);
    parts
}

/// Two pseudo-terminal pairs and the copying between their masters: QEMU's UART opens slave A,
/// listeners open slave B ([`PtyRelay::device`]). The test holds both masters and slave A for
/// the whole test, so neither QEMU exiting nor a listener closing its device hangs up the
/// other side or drops bytes in flight.
struct PtyRelay {
    /// Slave A's path, for QEMU.
    qemu_side: PathBuf,
    /// Slave B's path, for listeners.
    device: PathBuf,
    stop: Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
    _slave_a: serialport::TTYPort,
}

impl PtyRelay {
    fn start() -> PtyRelay {
        use serialport::{SerialPort, TTYPort};
        let (mut master_a, slave_a) = TTYPort::pair().expect("pty pair A");
        let (mut master_b, slave_b) = TTYPort::pair().expect("pty pair B");
        let qemu_side = PathBuf::from(slave_a.name().expect("slave A's name"));
        let device = PathBuf::from(slave_b.name().expect("slave B's name"));
        // Listeners open slave B by its path, and close it when they stop.
        drop(slave_b);
        for m in [&mut master_a, &mut master_b] {
            m.set_timeout(Duration::from_millis(20)).unwrap();
        }
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (a2, b2) = (
            master_a.try_clone_native().unwrap(),
            master_b.try_clone_native().unwrap(),
        );
        let threads = [(master_a, b2), (master_b, a2)]
            .into_iter()
            .map(|(from, to)| {
                let stop = stop.clone();
                std::thread::spawn(move || copy_until(from, to, &stop))
            })
            .collect();
        PtyRelay {
            qemu_side,
            device,
            stop,
            threads,
            _slave_a: slave_a,
        }
    }
}

impl Drop for PtyRelay {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::SeqCst);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Copies `from` to `to` until `stop`. A master whose slave nobody has open reads as an error
/// (no listener running): wait and try again.
fn copy_until(
    mut from: serialport::TTYPort,
    mut to: serialport::TTYPort,
    stop: &std::sync::atomic::AtomicBool,
) {
    use std::io::Read;
    let mut buf = [0u8; 4096];
    while !stop.load(std::sync::atomic::Ordering::SeqCst) {
        let n = match from.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            Err(_) => {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
        };
        let mut rest = &buf[..n];
        while !rest.is_empty() && !stop.load(std::sync::atomic::Ordering::SeqCst) {
            match to.write(rest) {
                Ok(k) => rest = &rest[k..],
                Err(_) => std::thread::sleep(Duration::from_millis(5)),
            }
        }
    }
}

/// QEMU with the firmware, paused, UART1 on slave A of a [`PtyRelay`]; `pty` is slave B.
struct Qemu {
    child: Child,
    qmp: BufReader<UnixStream>,
    pty: PathBuf,
    log: PathBuf,
    // Dropped after `child` is stopped (fields drop in order): QEMU's device outlives QEMU.
    _relay: PtyRelay,
}

impl Qemu {
    fn start(elf: &Path, dir: &Path) -> Qemu {
        let relay = PtyRelay::start();
        let sock = dir.join("qmp.sock");
        let log = dir.join("qemu.log");
        let f = std::fs::File::create(&log).unwrap();
        let mut child = Command::new("bash")
            .arg(repo_root().join("scripts/firmware.sh"))
            .arg("qemu")
            .arg(elf)
            .args(["--timeout", "120", "--uart1", "chardev:u1", "--raw"])
            .arg(dir.join("defmt.raw"))
            .arg("--")
            .arg("-chardev")
            .arg(format!("serial,id=u1,path={}", relay.qemu_side.display()))
            .args(["-S", "-qmp"])
            .arg(format!("unix:{},server=on,wait=off", sock.display()))
            .stdin(Stdio::null())
            .stdout(Stdio::from(f.try_clone().unwrap()))
            .stderr(Stdio::from(f))
            .spawn()
            .expect("starting scripts/firmware.sh qemu");
        let t0 = Instant::now();
        let stream = loop {
            if let Ok(s) = UnixStream::connect(&sock) {
                break s;
            }
            if let Ok(Some(st)) = child.try_wait() {
                panic!("QEMU exited ({st}):\n{}", read(&log));
            }
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "no QMP socket after 30 s:\n{}",
                read(&log)
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        stream
            .set_read_timeout(Some(Duration::from_secs(30)))
            .unwrap();
        let mut q = Qemu {
            child,
            qmp: BufReader::new(stream),
            pty: relay.device.clone(),
            log,
            _relay: relay,
        };
        let mut greeting = String::new();
        q.qmp.read_line(&mut greeting).unwrap();
        assert!(greeting.contains("QMP"), "QMP greeting: {greeting}");
        q.execute("qmp_capabilities");
        q
    }

    /// A QMP command; skips events until its answer.
    fn execute(&mut self, cmd: &str) -> serde_json::Value {
        let s = self.qmp.get_mut();
        writeln!(s, "{{\"execute\":\"{cmd}\"}}").unwrap();
        loop {
            let mut line = String::new();
            let n = self.qmp.read_line(&mut line).unwrap();
            assert!(n > 0, "QMP closed during {cmd}");
            let v: serde_json::Value = serde_json::from_str(&line).unwrap();
            if v.get("return").is_some() {
                return v;
            }
            assert!(v.get("error").is_none(), "QMP {cmd}: {v}");
        }
    }

    fn wait(mut self, limit: Duration) -> ExitStatus {
        let t0 = Instant::now();
        loop {
            if let Some(st) = self.child.try_wait().unwrap() {
                return st;
            }
            if t0.elapsed() > limit {
                let _ = self.child.kill();
                panic!("QEMU still running after {limit:?}:\n{}", read(&self.log));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        // The script runs QEMU under `timeout`; killing the script's shell leaves it to that
        // timeout, so end the whole process group politely via QMP first.
        if matches!(self.child.try_wait(), Ok(None)) {
            let s = self.qmp.get_mut();
            let _ = writeln!(s, "{{\"execute\":\"quit\"}}");
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

/// A listener on its own thread.
struct Running {
    ctl: Arc<Control>,
    thread: std::thread::JoinHandle<anyhow::Result<ListenStats>>,
}

fn start_listener(args: ListenArgs) -> Running {
    let ctl = Control::new();
    let c = ctl.clone();
    let thread = std::thread::spawn(move || run(&args, c));
    let t0 = Instant::now();
    while !ctl.connected.load(std::sync::atomic::Ordering::SeqCst) {
        assert!(!thread.is_finished(), "the listener stopped before opening");
        assert!(t0.elapsed() < Duration::from_secs(30), "listener not open");
        std::thread::sleep(Duration::from_millis(5));
    }
    Running { ctl, thread }
}

impl Running {
    fn wait_for(&self, what: &str, limit: Duration, f: impl Fn(&ListenStats) -> bool) {
        let t0 = Instant::now();
        loop {
            if self.ctl.stats().is_some_and(|s| f(&s)) {
                return;
            }
            assert!(!self.thread.is_finished(), "listener ended before {what}");
            assert!(
                t0.elapsed() < limit,
                "{what}: not within {limit:?}: {:?}",
                self.ctl.stats()
            );
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    fn join(self, limit: Duration) -> ListenStats {
        let t0 = Instant::now();
        while !self.thread.is_finished() {
            if t0.elapsed() > limit {
                self.ctl
                    .stop
                    .store(true, std::sync::atomic::Ordering::SeqCst);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        self.thread
            .join()
            .expect("listener panicked")
            .expect("listener failed")
    }
}

fn listen_args(pty: &Path, out: &Path, send: &Path) -> ListenArgs {
    let mut a = ListenArgs::new(pty, out);
    a.send = Some(send.to_path_buf());
    a.save_every = 0.5;
    a
}

#[test]
fn listener_on_a_pty_saves_the_host_replays_map() {
    if !ogm_tests::firmware_available("listener_on_a_pty_saves_the_host_replays_map") {
        return;
    }
    let t0 = Instant::now();
    let elf = elf();
    let dir = tempfile::tempdir().unwrap();
    let (config, input) = simulated_run(5);
    let send = dir.path().join("send.jsonl");
    std::fs::write(&send, send_lines(&input)).unwrap();
    let out = dir.path().join("listen");

    let mut qemu = Qemu::start(&elf, dir.path());
    let mut args = listen_args(&qemu.pty, &out, &send);
    args.until_done = true;
    args.hello_wait = 30.0; // QEMU is paused: wait for the Hello
    let l = start_listener(args);
    qemu.execute("cont");
    let st = l.join(Duration::from_secs(120));
    let status = qemu.wait(Duration::from_secs(30));
    eprintln!("listener: {st:?}");
    assert_eq!(status.code(), Some(0), "firmware exit status");
    let done = st.done.expect("the robot's Done");
    assert_eq!(done.scans as usize, SCANS);
    assert_eq!((st.scans_seen, st.scans_missed), (SCANS as u64, 0));
    assert_eq!((st.bad_frames, st.garbage_bytes, st.bad_tiles), (0, 0, 0));
    // Every scan's ranges placed at its pose for the live view; the last turn's points.
    assert_eq!((st.ranges_placed, st.bad_ranges), (SCANS as u64, 0));
    assert!(st.scan_points >= 45, "{} points", st.scan_points);
    assert_eq!(st.sent as usize, input.units.len(), "every line sent");
    assert_eq!(st.robot.map(|c| c.scans as usize), Some(SCANS));
    assert_eq!(st.config, Some(config));

    // The host replay: the same input through ogm-core, with the firmware's reported updates.
    let events = decode_file(&out.join(CAPTURE_FILE)).unwrap();
    let hello = events
        .iter()
        .find_map(|e| match e {
            DeviceEvent::Hello(h) => Some(h.clone()),
            _ => None,
        })
        .expect("Hello in the capture");
    // The firmware's application run on the host over the same input (`host-sim firmware`'s
    // replay), with the sampler work the firmware reported.
    let (host, report) = replay_map(&input.bytes, &events).expect("host replay");
    let (w, h) = (usize::from(hello.width), usize::from(hello.height));
    // The listener's map, cell for cell (rebuilt from its capture).
    let mut again = Listener::new();
    again.push(&std::fs::read(out.join(CAPTURE_FILE)).unwrap());
    let lm = again.map().expect("a map");
    assert_eq!(
        lm.log_odds, host.log_odds,
        "log-odds differ from the replay"
    );
    assert_eq!(
        lm.counts, host.counts,
        "marginal counts differ from the replay"
    );
    assert_eq!(lm.sample, host.sample, "sample differs from the replay");
    assert!(
        again.have_counts().iter().all(|&x| x),
        "a marginal tile never came"
    );
    assert!(host.log_odds.iter().filter(|&&l| l != 0).count() > 1000);

    // The replay's map through the same writer = the listener's files, byte for byte.
    let expected = dir.path().join("expected");
    let one = counts_of_one(Some(&config), Some(&hello), report.samples);
    let all = vec![true; w * h];
    for (stem, layer) in [
        ("map", MapLayer::Marginals),
        ("log_odds", MapLayer::LogOdds),
    ] {
        let probs = stream_probabilities(&host, &all, one, layer);
        let world = probabilities_to_world(
            &probs,
            w,
            h,
            f64::from(config.cell_mm) / 1000.0,
            (
                f64::from(config.origin_x_mm) / 1000.0,
                f64::from(config.origin_y_mm) / 1000.0,
            ),
            DEFAULT_OCCUPIED_THRESH,
            DEFAULT_FREE_THRESH,
        );
        export_world(&expected.join(format!("{stem}.yaml")), &world).unwrap();
        for ext in ["pgm", "yaml", "png"] {
            let f = format!("{stem}.{ext}");
            assert!(
                std::fs::read(out.join(&f)).unwrap() == std::fs::read(expected.join(&f)).unwrap(),
                "{f}: the listener's file differs from the host replay's"
            );
        }
    }
    eprintln!("equality part: {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn killed_listener_restarts_resynchronises_and_counts_what_it_missed() {
    if !ogm_tests::firmware_available(
        "killed_listener_restarts_resynchronises_and_counts_what_it_missed",
    ) {
        return;
    }
    let t0 = Instant::now();
    let elf = elf();
    let dir = tempfile::tempdir().unwrap();
    let (_, input) = simulated_run(6);
    let parts = split_before_scans(&input, &[2, 5]);
    let (first, gap, rest) = (&parts[0], &parts[1], &parts[2]);
    let send_a = dir.path().join("a.jsonl");
    let send_b = dir.path().join("b.jsonl");
    std::fs::write(&send_a, send_lines(first)).unwrap();
    std::fs::write(&send_b, send_lines(rest)).unwrap();
    let out = dir.path().join("listen");

    let mut qemu = Qemu::start(&elf, dir.path());
    // A: settings and scans 0-1; killed once scan 1's report is in.
    let mut a = listen_args(&qemu.pty, &out, &send_a);
    a.hello_wait = 30.0;
    let la = start_listener(a);
    qemu.execute("cont");
    la.wait_for("scan 1's report", Duration::from_secs(60), |s| {
        s.last_seq == Some(1)
    });
    la.ctl
        .abort
        .store(true, std::sync::atomic::Ordering::SeqCst);
    let sa = la.join(Duration::from_secs(10));
    assert_eq!(sa.scans_seen, 2, "{sa:?}");

    // Nobody listening: scans 2-4 go in, their stream goes nowhere.
    let mut port = open_port(&qemu.pty, 921_600, Duration::from_millis(20)).unwrap();
    let mut dec = StreamDecoder::new();
    let (mut off, mut last_scan, mut drained) = (0, None, false);
    let mut buf = [0u8; 4096];
    let t1 = Instant::now();
    while !drained {
        assert!(
            t1.elapsed() < Duration::from_secs(60),
            "scans 2-4 not processed"
        );
        if off < gap.bytes.len() {
            if let Ok(n) = port.write(&gap.bytes[off..]) {
                off += n;
            }
        }
        if let Ok(n) = std::io::Read::read(&mut port, &mut buf) {
            for e in dec.push(&buf[..n]).into_iter().flatten() {
                match e {
                    DeviceEvent::Scan(r) => last_scan = Some(r.seq),
                    DeviceEvent::Counters(_) if last_scan == Some(4) => drained = true,
                    _ => {}
                }
            }
        }
    }
    drop(port);

    // B: resumes A's capture, sends scans 5-7 and Finish.
    let mut b = listen_args(&qemu.pty, &out, &send_b);
    b.until_done = true;
    b.hello_wait = 0.2; // a running robot says no Hello
    let sb = start_listener(b).join(Duration::from_secs(120));
    let status = qemu.wait(Duration::from_secs(30));
    eprintln!("restarted listener: {sb:?}");
    assert_eq!(status.code(), Some(0), "firmware exit status");
    assert_eq!(sb.restarts, 1);
    assert_eq!(sb.gaps, vec![Gap { first: 2, last: 4 }]);
    assert_eq!(sb.scans_missed, 3);
    assert_eq!(sb.scans_seen, 5, "scans 0, 1 (before) and 5, 6, 7 (after)");
    assert_eq!(sb.last_seq, Some(7));
    assert!(sb.frames > sa.frames + 20, "no frames after the restart");
    assert_eq!(sb.done.map(|d| d.scans as usize), Some(SCANS));
    assert_eq!(sb.robot.map(|c| c.scans as usize), Some(SCANS));
    assert!(
        sb.hello.is_some() && sb.config.is_some(),
        "kept from before"
    );
    let status_json: serde_json::Value =
        serde_json::from_str(&read(&out.join("status.json"))).unwrap();
    assert_eq!(status_json["scans_missed"], 3);
    for f in ["map.yaml", "map.pgm", "map.png", "log_odds.pgm"] {
        assert!(out.join(f).exists(), "{f}");
    }
    eprintln!("restart part: {:.1} s", t0.elapsed().as_secs_f64());
}
