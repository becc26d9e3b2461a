//! The listener's I/O loop around a serial port (or a captured file) and the command.

use std::collections::VecDeque;
use std::io::{BufRead, IsTerminal, Read, Write};
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::mpsc::Sender;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context};
use ogm_core::wire::HostMsg;

use super::args::{default_config, ListenArgs};
use super::control::Control;
use super::port::{open_port, transient};
use super::send::{parse_send_line, sender, SendSource, ToSender};
use super::stats::{ListenStats, Notice};
use super::{Listener, CAPTURE_FILE};
use crate::stream::StreamDecoder;

/// What the loop reads from.
enum Source {
    Serial(Box<dyn serialport::SerialPort>),
    File(std::fs::File),
}

/// Prints notices and the status line on stderr.
struct Console {
    quiet: bool,
    tty: bool,
    last: Instant,
    shown: bool,
}

impl Console {
    fn line(&mut self, text: &str) {
        if self.tty && self.shown {
            eprint!("\r\x1b[K");
            self.shown = false;
        }
        eprintln!("{text}");
    }

    fn status(&mut self, l: &Listener, force: bool) {
        if self.quiet {
            return;
        }
        let every = if self.tty {
            Duration::from_millis(250)
        } else {
            Duration::from_secs(10)
        };
        if !force && self.last.elapsed() < every {
            return;
        }
        self.last = Instant::now();
        if self.tty {
            eprint!("\r\x1b[K{}", l.status_line());
            let _ = std::io::stderr().flush();
            self.shown = true;
        } else {
            eprintln!("{}", l.status_line());
        }
    }

    fn finish(&mut self) {
        if self.tty && self.shown {
            eprintln!();
            self.shown = false;
        }
    }
}

/// Runs the listener until the input ends (a regular file), the robot is done (`until_done`),
/// or `ctl` says stop (save) or abort (no save). Returns the final counters.
pub fn run(args: &ListenArgs, ctl: Arc<Control>) -> anyhow::Result<ListenStats> {
    let port_path = args
        .port
        .clone()
        .ok_or_else(|| anyhow::anyhow!("--port DEV is required"))?;
    ensure!(
        args.save_every.is_finite() && args.save_every >= 0.0,
        "--save-every must be 0 or more seconds"
    );
    ensure!(
        args.hello_wait.is_finite() && args.hello_wait >= 0.0,
        "--hello-wait must be 0 or more seconds"
    );
    ensure!(args.baud > 0, "--baud must be positive");
    let source = SendSource::of(args)?;
    let is_file = std::fs::metadata(&port_path).is_ok_and(|m| m.is_file());
    if is_file {
        ensure!(
            matches!(source, SendSource::Nothing),
            "{}: a file, not a device: nothing can be sent to it",
            port_path.display()
        );
        // A capture must be one: checked before anything is written.
        let bytes = std::fs::read(&port_path)
            .with_context(|| format!("{}: cannot read", port_path.display()))?;
        ensure!(!bytes.is_empty(), "{}: file is empty", port_path.display());
        ensure!(
            StreamDecoder::new().push(&bytes).iter().any(Result::is_ok),
            "{}: wrong format: not a map stream (no valid frame in {} bytes)",
            port_path.display(),
            bytes.len()
        );
    }
    let capture = args.out.join(CAPTURE_FILE);
    if is_file && std::fs::canonicalize(&port_path).ok() == std::fs::canonicalize(&capture).ok() {
        bail!(
            "{}: is the listener's own capture; read a copy, or use `host-sim export --stream`",
            port_path.display()
        );
    }
    // Open first: a wrong device is an error before anything is written.
    let timeout = Duration::from_millis(100);
    let mut src = Some(if is_file {
        Source::File(
            std::fs::File::open(&port_path)
                .with_context(|| format!("{}: cannot read", port_path.display()))?,
        )
    } else {
        Source::Serial(open_port(&port_path, args.baud, timeout)?)
    });
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create directory", args.out.display()))?;
    let mut l = Listener::with_capture(&capture, args.fresh)?;
    l.set_send_back(!args.no_restore);
    if let Some(path) = &args.mcap {
        l.record_to(path)?;
    }
    let live_addr = match &args.live {
        Some(addr) => Some(l.serve_live(addr)?),
        None => None,
    };
    let mut con = Console {
        quiet: args.quiet,
        tty: std::io::stderr().is_terminal(),
        last: Instant::now(),
        shown: false,
    };
    if let Some(a) = live_addr {
        con.line(&format!(
            "live view: ws://{a} (Foxglove Studio: Open connection → Foxglove WebSocket)"
        ));
    }
    if l.stats().restarts > 0 {
        con.line(&format!(
            "resumed {}: {} bytes, {} scans seen (last {}); restart {}",
            capture.display(),
            l.stats().bytes,
            l.stats().scans_seen,
            l.stats()
                .last_seq
                .map_or("-".into(), |s: u32| s.to_string()),
            l.stats().restarts
        ));
    }
    ctl.connected.store(true, Ordering::SeqCst);
    ctl.publish(&l);

    // The sender thread, with its own handle on the device.
    let (tx, rx) = std::sync::mpsc::channel::<ToSender>();
    // Stored tiles go back to the robot through the sender too.
    let sending = !matches!(source, SendSource::Nothing) || args.default_config || !args.no_restore;
    let mut sender_thread = None;
    if sending {
        let queue: VecDeque<Vec<u8>> = match &source {
            SendSource::Items(v) => v.iter().cloned().collect(),
            _ => VecDeque::new(),
        };
        if let Some(Source::Serial(p)) = &src {
            let clone = p
                .try_clone()
                .with_context(|| format!("{}: cannot clone the port", port_path.display()))?;
            let _ = tx.send(ToSender::Port(clone));
        }
        let default = args.default_config.then(default_config);
        let c = ctl.clone();
        sender_thread = Some(std::thread::spawn(move || sender(rx, queue, default, c)));
        if matches!(source, SendSource::Stdin) {
            let tx = tx.clone();
            // Detached: it may block on stdin forever; it holds no device.
            std::thread::spawn(move || {
                let stdin = std::io::stdin();
                for (i, line) in stdin.lock().lines().enumerate() {
                    let Ok(line) = line else { break };
                    match parse_send_line(&line) {
                        Ok(Some(b)) => {
                            if tx.send(ToSender::Item(b)).is_err() {
                                break;
                            }
                        }
                        Ok(None) => {}
                        Err(e) => eprintln!("error: stdin:{}: {e} (line skipped)", i + 1),
                    }
                }
            });
        }
    }

    let result = read_loop(args, &port_path, &ctl, &mut l, &mut src, &tx, &mut con);
    // Stop the sender and wait for it, so that the device is closed when this returns.
    let _ = tx.send(ToSender::Stop);
    drop(tx);
    if let Some(t) = sender_thread {
        let _ = t.join();
    }
    drop(src);
    ctl.connected.store(false, Ordering::SeqCst);
    l.stats_mut().sent = ctl.sent.load(Ordering::SeqCst);
    ctl.publish(&l);
    if ctl.abort.load(Ordering::SeqCst) {
        return Ok(l.stats().clone());
    }
    // Whatever ended the loop, save what arrived.
    let saved = l.save(&args.out);
    let recorded = l.finish_recording();
    con.status(&l, true);
    con.finish();
    match recorded {
        Ok(Some(f)) => con.line(&format!("wrote {}", f.display())),
        Ok(None) => {}
        Err(e) => con.line(&format!("warning: {e:#}")),
    }
    match saved {
        Ok(files) => {
            for f in files {
                con.line(&format!("wrote {}", f.display()));
            }
        }
        Err(e) => {
            result?;
            return Err(e);
        }
    }
    result?;
    Ok(l.stats().clone())
}

fn read_loop(
    args: &ListenArgs,
    port_path: &Path,
    ctl: &Arc<Control>,
    l: &mut Listener,
    src: &mut Option<Source>,
    tx: &Sender<ToSender>,
    con: &mut Console,
) -> anyhow::Result<()> {
    let name = port_path.display().to_string();
    let opened = Instant::now();
    let mut go_sent = false;
    let mut last_save = Instant::now();
    let mut lost_at: Option<Instant> = None;
    let mut backoff = Duration::from_millis(100);
    let mut next_try = Instant::now();
    let mut last_error = String::new();
    let mut buf = vec![0u8; 16 * 1024];
    loop {
        if ctl.stopping() {
            if let Some(t) = lost_at {
                l.stats_mut().disconnected_secs += t.elapsed().as_secs_f64();
            }
            return Ok(());
        }
        if !go_sent && opened.elapsed().as_secs_f64() >= args.hello_wait {
            go_sent = true;
            let _ = tx.send(ToSender::Go(false));
        }
        l.live_tick();
        if args.save_every > 0.0
            && last_save.elapsed().as_secs_f64() >= args.save_every
            && l.dirty()
        {
            l.stats_mut().sent = ctl.sent.load(Ordering::SeqCst);
            if let Err(e) = l.save(&args.out) {
                con.line(&format!("error: saving: {e:#}"));
            }
            last_save = Instant::now();
        }
        let Some(s) = src.as_mut() else {
            // Disconnected: reopen with a back-off.
            if Instant::now() < next_try {
                std::thread::sleep(Duration::from_millis(20));
                con.status(l, false);
                continue;
            }
            match open_port(port_path, args.baud, Duration::from_millis(100)) {
                Ok(p) => {
                    if let Some(t) = lost_at.take() {
                        l.stats_mut().disconnected_secs += t.elapsed().as_secs_f64();
                    }
                    l.reconnected();
                    if let Ok(c) = p.try_clone() {
                        let _ = tx.send(ToSender::Port(c));
                    }
                    con.line(&format!(
                        "{name}: reopened (reconnect {})",
                        l.stats().reconnects
                    ));
                    *src = Some(Source::Serial(p));
                    ctl.connected.store(true, Ordering::SeqCst);
                    backoff = Duration::from_millis(100);
                }
                Err(e) => {
                    let msg = format!("{e:#}");
                    if msg != last_error {
                        con.line(&format!("{msg}; retrying"));
                        last_error = msg;
                    }
                    next_try = Instant::now() + backoff;
                    backoff = (backoff * 2).min(Duration::from_secs(2));
                }
            }
            continue;
        };
        let got = match s {
            Source::Serial(p) => p.read(&mut buf),
            Source::File(f) => f.read(&mut buf),
        };
        match got {
            Ok(0) => {
                if matches!(s, Source::File(_)) {
                    return Ok(()); // end of the capture
                }
                lose(src, &mut lost_at, ctl, con, &format!("{name}: hung up"));
                last_error.clear();
            }
            Ok(n) => {
                for notice in l.push(&buf[..n]) {
                    con.line(&notice.to_string());
                    match notice {
                        Notice::Hello(_) => {
                            if go_sent {
                                let _ = tx.send(ToSender::Hello);
                            } else {
                                go_sent = true;
                                let _ = tx.send(ToSender::Go(true));
                            }
                        }
                        Notice::Done(_) if args.until_done => {
                            ctl.publish(l);
                            return Ok(());
                        }
                        _ => {}
                    }
                }
                for frame in l.take_outgoing() {
                    let _ = tx.send(ToSender::Item(frame));
                }
                ctl.publish(l);
            }
            Err(e) if transient(&e) => {}
            Err(e) => {
                if matches!(s, Source::File(_)) {
                    bail!("{name}: read error: {e}");
                }
                lose(src, &mut lost_at, ctl, con, &format!("{name}: lost ({e})"));
                last_error.clear();
            }
        }
        if src.is_none() {
            next_try = Instant::now() + Duration::from_millis(100);
        }
        con.status(l, false);
    }
}

fn lose(
    src: &mut Option<Source>,
    lost_at: &mut Option<Instant>,
    ctl: &Control,
    con: &mut Console,
    why: &str,
) {
    *src = None;
    *lost_at = Some(Instant::now());
    ctl.connected.store(false, Ordering::SeqCst);
    con.line(&format!("{why}; reopening"));
}

/// `host-sim listen`.
pub fn cli(args: &ListenArgs) -> anyhow::Result<()> {
    if args.print_config {
        println!(
            "{}",
            serde_json::to_string(&HostMsg::Config(default_config()))?
        );
        return Ok(());
    }
    let ctl = Control::new();
    // Ctrl-C / SIGTERM: save and stop; a second Ctrl-C exits at once.
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(sig, 130, ctl.stop.clone())
            .context("installing the signal handler")?;
        signal_hook::flag::register(sig, ctl.stop.clone())
            .context("installing the signal handler")?;
    }
    let stats = run(args, ctl)?;
    println!(
        "{} frames, {} bad ({} CRC), {} garbage bytes; {} scans seen, {} missed; {} reconnects, {} restarts",
        stats.frames,
        stats.bad_frames,
        stats.crc_errors,
        stats.garbage_bytes,
        stats.scans_seen,
        stats.scans_missed,
        stats.reconnects,
        stats.restarts
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::stats::Gap;
    use super::super::test_stream::{config, frame, hello, stream};
    use super::super::STATUS_FILE;
    use super::*;
    use crate::stream::host_frame;
    use ogm_core::wire::DeviceMsg;

    #[test]
    fn run_on_a_captured_file_saves_at_its_end() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("capture.bin");
        std::fs::write(&input, stream(&[0, 1, 2, 3])).unwrap();
        let out = dir.path().join("out");
        let mut args = ListenArgs::new(&input, &out);
        args.quiet = true;
        let st = run(&args, Control::new()).unwrap();
        assert_eq!(st.scans_seen, 4);
        assert_eq!(st.saves, 1);
        for f in [
            "map.yaml",
            "map.pgm",
            "map.png",
            "log_odds.yaml",
            "log_odds.pgm",
            "log_odds.png",
            STATUS_FILE,
            CAPTURE_FILE,
        ] {
            assert!(out.join(f).exists(), "{f}");
        }
        assert_eq!(
            std::fs::read(out.join(CAPTURE_FILE)).unwrap(),
            std::fs::read(&input).unwrap()
        );
        // Bad input: clear one-line errors, no panic.
        let e = run(
            &ListenArgs::new(dir.path().join("nope"), &out),
            Control::new(),
        )
        .unwrap_err();
        assert_eq!(
            format!("{e:#}"),
            format!(
                "{}: no such file or device",
                dir.path().join("nope").display()
            )
        );
        let mut a = ListenArgs::new(&input, &out);
        a.send = Some(dir.path().join("missing.jsonl"));
        let e = run(&a, Control::new()).unwrap_err();
        assert!(
            format!("{e:#}").ends_with("missing.jsonl: file not found"),
            "{e:#}"
        );
        let e = run(&ListenArgs::new(dir.path(), &out), Control::new()).unwrap_err();
        assert!(format!("{e:#}").contains("is a directory"), "{e:#}");
        // Empty, truncated and wrong-format inputs: one line naming the file.
        let f = dir.path().join("f");
        let out2 = dir.path().join("out2");
        let err = |a: &ListenArgs| format!("{:#}", run(a, Control::new()).unwrap_err());
        let fp = f.display().to_string();
        std::fs::write(&f, b"").unwrap();
        assert_eq!(
            err(&ListenArgs::new(&f, &out2)),
            format!("{fp}: file is empty")
        );
        std::fs::write(&f, b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR").unwrap();
        assert!(err(&ListenArgs::new(&f, &out2))
            .starts_with(&format!("{fp}: wrong format: not a map stream")));
        assert!(!out2.exists(), "nothing written for a bad capture");
        let dev = ListenArgs::new("/dev/null", &out2);
        assert!(err(&dev).starts_with("/dev/null: cannot open as a serial port"));
        for (content, why) in [
            (&b""[..], "no message to send"),
            (&b"{\"ScanEnd\":{\"seq\":1,\"poi"[..], "1: not JSON"),
            (&b"\xff\xfe\x00binary"[..], "not UTF-8"),
        ] {
            std::fs::write(&f, content).unwrap();
            let mut a = ListenArgs::new("/dev/null", &out2);
            a.send = Some(f.clone());
            let e = err(&a);
            assert!(e.starts_with(&fp) && e.contains(why), "{e}");
            let mut a = ListenArgs::new("/dev/null", &out2);
            a.send_raw = Some(f.clone());
            if content.is_empty() {
                assert_eq!(err(&a), format!("{fp}: file is empty"));
            }
        }
    }

    /// Reads from `port` until `n` bytes came (or 10 s passed).
    fn read_n(port: &mut dyn serialport::SerialPort, n: usize) -> Vec<u8> {
        let mut got = Vec::new();
        let mut buf = [0u8; 4096];
        let t0 = Instant::now();
        while got.len() < n && t0.elapsed() < Duration::from_secs(10) {
            if let Ok(k) = port.read(&mut buf) {
                got.extend_from_slice(&buf[..k]);
            }
        }
        got
    }

    fn wait(what: &str, f: impl Fn() -> bool) {
        let t0 = Instant::now();
        while !f() {
            assert!(t0.elapsed() < Duration::from_secs(20), "{what}");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// A pseudo-terminal pair stands in for a USB serial adapter: the listener opens the device
    /// through a symlink (as udev's /dev/serial/by-id links), "unplug" closes the robot's end
    /// and removes the link, "replug" makes a new pair behind the same link.
    #[test]
    fn unplug_and_replug_reopens_counts_the_gap_and_keeps_sending() {
        use serialport::{SerialPort, TTYPort};
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("robot");
        let plug = || -> TTYPort {
            let (mut robot, dev) = TTYPort::pair().expect("a pseudo-terminal pair");
            let name = dev.name().expect("the pty's name");
            drop(dev);
            let _ = std::fs::remove_file(&link);
            std::os::unix::fs::symlink(name, &link).unwrap();
            robot.set_timeout(Duration::from_millis(50)).unwrap();
            robot
        };
        let mut robot = plug();
        let send = dir.path().join("send.jsonl");
        std::fs::write(&send, "{\"raw\":\"0102\"}\n\"Finish\"\n").unwrap();
        let out = dir.path().join("out");
        let mut args = ListenArgs::new(&link, &out);
        args.send = Some(send);
        args.default_config = true;
        args.hello_wait = 60.0; // send only after the Hello
        args.save_every = 0.0;
        args.quiet = true;
        let ctl = Control::new();
        let c = ctl.clone();
        let t = std::thread::spawn(move || run(&args, c));
        wait("listener open", || ctl.connected.load(Ordering::SeqCst));
        let stats = || ctl.stats().unwrap_or_default();

        // Boot: the Hello makes it send the default settings, then the file's lines.
        let s = stream(&[0, 1, 2, 3]);
        let first = stream(&[0, 1, 2]);
        robot.write_all(&first).unwrap();
        let cfg_frame = host_frame(&HostMsg::Config(default_config()));
        let finish = host_frame(&HostMsg::Finish);
        let expected = [cfg_frame.clone(), vec![1, 2], finish].concat();
        assert_eq!(read_n(&mut robot, expected.len()), expected);
        wait("scan 2", || stats().last_seq == Some(2));

        // Unplugged in the middle of scan 3's frames.
        robot.write_all(&s[first.len()..first.len() + 9]).unwrap();
        wait("9 more bytes", || {
            stats().bytes == s.len().min(first.len() + 9) as u64
        });
        drop(robot);
        std::fs::remove_file(&link).unwrap();
        wait("loss noticed", || !ctl.connected.load(Ordering::SeqCst));
        std::thread::sleep(Duration::from_millis(300)); // "no such device; retrying"

        // Replugged: scans 3-5 went nowhere; 6 and 7 arrive.
        let mut robot = plug();
        wait("reopened", || ctl.connected.load(Ordering::SeqCst));
        let hl = hello().len() + frame(&DeviceMsg::Configured(config())).len();
        robot.write_all(&stream(&[6, 7])[hl..]).unwrap();
        wait("scan 7", || stats().last_seq == Some(7));
        // The robot reboots: the sender (on the new device) sends the default settings again.
        robot.write_all(&hello()).unwrap();
        assert_eq!(read_n(&mut robot, cfg_frame.len()), cfg_frame);
        wait("second Hello", || stats().hellos == 2);

        ctl.stop.store(true, Ordering::SeqCst); // Ctrl-C
        let st = t.join().unwrap().unwrap();
        assert_eq!(st.reconnects, 1);
        assert!(st.disconnected_secs >= 0.3, "{}", st.disconnected_secs);
        assert_eq!(st.gaps, vec![Gap { first: 3, last: 5 }]);
        assert_eq!(st.scans_missed, 3);
        assert_eq!(st.scans_seen, 5);
        assert_eq!(st.bad_frames, 1, "scan 3's cut report");
        assert_eq!(st.garbage_bytes, 10);
        assert_eq!(st.sent, 2);
        assert_eq!(st.saves, 1, "saved on stop");
        // The new boot's (still empty) map and the counters were saved.
        assert!(out.join(STATUS_FILE).exists() && out.join("map.pgm").exists());
    }
}
