//! Host messages to the robot: the `--send` lines (JSON host messages or raw hex) and the
//! sender thread that writes them, surviving a device that comes and goes.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError, TryRecvError};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, ensure};
use ogm_core::config::RunConfig;
use ogm_core::wire::HostMsg;

use super::args::ListenArgs;
use super::control::Control;
use super::port::transient;
use crate::stream::host_frame;

/// One line of a `--send` file: a host message as JSON (serde's encoding of
/// [`HostMsg`]: `{"Config":{…}}`, `{"ScanStart":{"seq":0,"pose":{"x_mm":0,"y_mm":0,"heading":0}}}`,
/// `{"ScanEnd":{"seq":0,"points":360}}`, `{"Idle":{"seq":0,"period_us":1000000}}`, `"Finish"`),
/// or `{"raw":"HEX"}` for bytes sent as they are (LD06 packets). Blank lines and lines starting
/// with `#` are nothing (`Ok(None)`).
pub fn parse_send_line(line: &str) -> anyhow::Result<Option<Vec<u8>>> {
    let line = line.trim();
    if line.is_empty() || line.starts_with('#') {
        return Ok(None);
    }
    let v: serde_json::Value =
        serde_json::from_str(line).map_err(|e| anyhow::anyhow!("not JSON: {e}"))?;
    if let Some(obj) = v.as_object() {
        if let Some(raw) = obj.get("raw") {
            ensure!(obj.len() == 1, "a raw line has only the key \"raw\"");
            let hex = raw
                .as_str()
                .ok_or_else(|| anyhow::anyhow!("\"raw\" must be a string of hex digits"))?;
            return Ok(Some(parse_hex(hex)?));
        }
    }
    let msg: HostMsg = serde_json::from_value(v).map_err(|e| {
        anyhow::anyhow!(
            "not a host message ({e}); expected Config, ScanStart, ScanEnd, Idle, \"Finish\" or {{\"raw\":\"HEX\"}}"
        )
    })?;
    Ok(Some(host_frame(&msg)))
}

fn parse_hex(s: &str) -> anyhow::Result<Vec<u8>> {
    let s: String = s.chars().filter(|c| !c.is_ascii_whitespace()).collect();
    ensure!(s.len() % 2 == 0, "odd number of hex digits");
    let digit = |c: u8| -> anyhow::Result<u8> {
        match c {
            b'0'..=b'9' => Ok(c - b'0'),
            b'a'..=b'f' => Ok(c - b'a' + 10),
            b'A'..=b'F' => Ok(c - b'A' + 10),
            _ => bail!("`{}` is not a hex digit", char::from(c)),
        }
    };
    s.as_bytes()
        .chunks(2)
        .map(|p| Ok(digit(p[0])? << 4 | digit(p[1])?))
        .collect()
}

/// Reads a `--send` file: one entry per non-empty line; the first bad line is an error naming
/// the file and the line.
pub fn read_send_file(path: &Path) -> anyhow::Result<Vec<Vec<u8>>> {
    let text = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{}: file not found", path.display())
        }
        Err(e) => bail!("{}: cannot read: {e}", path.display()),
    };
    let text = String::from_utf8(text)
        .map_err(|e| anyhow::anyhow!("{}: not UTF-8 text: {e}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        match parse_send_line(line) {
            Ok(Some(b)) => out.push(b),
            Ok(None) => {}
            Err(e) => bail!("{}:{}: {e}", path.display(), i + 1),
        }
    }
    ensure!(!out.is_empty(), "{}: no message to send", path.display());
    Ok(out)
}

/// What to send to the robot.
#[derive(Clone, Debug)]
pub enum SendSource {
    /// Nothing.
    Nothing,
    /// These byte strings, in order (lines of a file, or a raw file as one).
    Items(Vec<Vec<u8>>),
    /// `--send` lines read from stdin as they come (a bad line is reported and skipped).
    Stdin,
}

impl SendSource {
    /// The source `--send` / `--send-raw` give (files are read and checked now).
    pub fn of(args: &ListenArgs) -> anyhow::Result<SendSource> {
        if let Some(p) = &args.send {
            if p.as_os_str() == "-" {
                return Ok(SendSource::Stdin);
            }
            return Ok(SendSource::Items(read_send_file(p)?));
        }
        if let Some(p) = &args.send_raw {
            let b = match std::fs::read(p) {
                Ok(b) => b,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    bail!("{}: file not found", p.display())
                }
                Err(e) => bail!("{}: cannot read: {e}", p.display()),
            };
            ensure!(!b.is_empty(), "{}: file is empty", p.display());
            return Ok(SendSource::Items(vec![b]));
        }
        Ok(SendSource::Nothing)
    }
}

/// Messages to the sender thread.
pub(super) enum ToSender {
    /// A (new) device to write to.
    Port(Box<dyn serialport::SerialPort>),
    /// Start sending: the robot said Hello (`true`), or none came in time.
    Go(bool),
    /// The robot said Hello (again).
    Hello,
    /// One more item (from stdin).
    Item(Vec<u8>),
    /// Stop.
    Stop,
}

/// The sender: writes the items in order once told to go; after a write error it waits for
/// the next device and sends the interrupted item again, whole (the robot ignores repeated
/// frames, and a cut one is garbage it skips).
pub(super) fn sender(
    rx: Receiver<ToSender>,
    mut queue: VecDeque<Vec<u8>>,
    default_config: Option<RunConfig>,
    ctl: Arc<Control>,
) {
    let mut port: Option<Box<dyn serialport::SerialPort>> = None;
    let mut go = false;
    // A Config went out since the last Hello (or the default one is due).
    let mut config_sent = false;
    let mut config_due = false;
    let is_config = |b: &[u8]| {
        matches!(b, [0, body @ .., 0] if {
            let mut body = body.to_vec();
            matches!(ogm_core::wire::decode::<HostMsg>(&mut body), Ok(HostMsg::Config(_)))
        })
    };
    loop {
        if ctl.stopping() {
            return;
        }
        let busy = go && port.is_some() && (!queue.is_empty() || config_due);
        let msg = if busy {
            match rx.try_recv() {
                Ok(m) => Some(m),
                Err(TryRecvError::Empty) => None,
                Err(TryRecvError::Disconnected) => return,
            }
        } else {
            match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(m) => Some(m),
                Err(RecvTimeoutError::Timeout) => None,
                Err(RecvTimeoutError::Disconnected) => return,
            }
        };
        match msg {
            Some(ToSender::Port(p)) => port = Some(p),
            Some(ToSender::Go(hello)) => {
                go = true;
                config_due = hello && default_config.is_some() && !config_sent;
            }
            Some(ToSender::Hello) => {
                config_sent = false;
                config_due = default_config.is_some();
            }
            Some(ToSender::Item(b)) => queue.push_back(b),
            Some(ToSender::Stop) => return,
            None => {}
        }
        if !(go && port.is_some()) {
            continue;
        }
        let (item, is_default) = match (config_due, default_config) {
            (true, Some(c)) if !queue.front().is_some_and(|b| is_config(b)) => {
                (host_frame(&HostMsg::Config(c)), true)
            }
            _ => match queue.front() {
                Some(b) => (b.clone(), false),
                None => {
                    config_due = false;
                    continue;
                }
            },
        };
        let Some(p) = port.as_mut() else { continue };
        match write_item(p.as_mut(), &item, &ctl) {
            Ok(true) => {
                if is_config(&item) {
                    config_sent = true;
                    config_due = false;
                }
                if !is_default {
                    queue.pop_front();
                    ctl.sent.fetch_add(1, Ordering::SeqCst);
                }
            }
            Ok(false) => return,
            Err(_) => port = None, // the reader reopens the device and hands it over
        }
    }
}

/// Writes `item` whole, retrying while the device is full; `Ok(false)` if told to stop.
fn write_item(
    port: &mut dyn serialport::SerialPort,
    item: &[u8],
    ctl: &Control,
) -> std::io::Result<bool> {
    let mut off = 0;
    while off < item.len() {
        if ctl.stopping() {
            return Ok(false);
        }
        match port.write(&item[off..]) {
            Ok(0) => return Err(std::io::ErrorKind::WriteZero.into()),
            Ok(n) => off += n,
            Err(e) if transient(&e) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::super::args::default_config;
    use super::*;

    #[test]
    fn bad_send_lines_name_their_line_and_the_default_settings_parse_back() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("send.jsonl");
        for (bad, why) in [
            ("{\"Config\":{\"cell_mm\":50}}", "missing field"),
            ("{\"Fly\":1}", "unknown variant"),
            ("{\"raw\":\"54f\"}", "odd number"),
            ("{\"raw\":\"zz\"}", "not a hex digit"),
            ("{\"raw\":7}", "string of hex"),
            ("{\"ScanEnd\":{\"seq\":-1,\"points\":3}}", "host message"),
            ("Finish", "not JSON"),
        ] {
            std::fs::write(&f, format!("\"Finish\"\n{bad}\n")).unwrap();
            let e = format!("{:#}", read_send_file(&f).unwrap_err());
            assert!(
                e.starts_with(&format!("{}:2: ", f.display())) && e.contains(why),
                "{bad}: {e}"
            );
        }
        std::fs::write(&f, "\n# nothing\n").unwrap();
        assert!(format!("{:#}", read_send_file(&f).unwrap_err()).contains("no message"));
        // The default settings print as a line that parses back.
        let line = serde_json::to_string(&HostMsg::Config(default_config())).unwrap();
        assert_eq!(
            parse_send_line(&line).unwrap(),
            Some(host_frame(&HostMsg::Config(default_config())))
        );
        // A settings file from before `free_update_q8` existed reads as the textbook model.
        let old = line.replace(
            &format!(",\"free_update_q8\":{}", default_config().free_update_q8),
            "",
        );
        assert!(!old.contains("free_update_q8"), "{old}");
        let want = RunConfig {
            free_update_q8: 256,
            ..default_config()
        };
        assert_eq!(
            parse_send_line(&old).unwrap(),
            Some(host_frame(&HostMsg::Config(want)))
        );
    }
}
