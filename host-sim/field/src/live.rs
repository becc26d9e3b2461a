//! The live view of a robot session (`host-sim listen --live [ADDR]`): a server of the Foxglove
//! WebSocket protocol (`foxglove.websocket.v1`) that Foxglove Studio connects to ("Open
//! connection" → "Foxglove WebSocket" → `ws://127.0.0.1:8765`). It offers the channels of the
//! MCAP recording ([`crate::recording::CHANNELS`]: both maps as `foxglove.Grid`, the robot's pose
//! as `foxglove.PoseInFrame`, JSON messages) and sends each subscriber every message published
//! after it subscribed, and the latest one of the channel right away.
//!
//! Binds to localhost unless given another address. A client's bytes are untrusted: its text
//! messages are parsed as JSON and anything but `subscribe` / `unsubscribe` with valid ids is
//! ignored; messages over [`MAX_CLIENT_MESSAGE`] bytes end its connection, and at most
//! [`MAX_CLIENTS`] are served at once. A slow client never blocks the listener: each client has
//! its own thread and a bounded queue, and a client whose queue is full misses messages
//! (counted) instead.
//!
//! Protocol (what this server uses of it): on connect the server sends `serverInfo` and
//! `advertise` (text, JSON); the client sends `subscribe` `{"op":"subscribe","subscriptions":
//! [{"id":S,"channelId":C}]}` and `unsubscribe` `{"op":"unsubscribe","subscriptionIds":[S]}`;
//! the server sends messages as binary frames: opcode `0x01`, subscription id (u32 LE), receive
//! time (u64 LE, ns since the Unix epoch), then the message's JSON.

use std::collections::BTreeMap;
use std::io::ErrorKind;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;
use serde_json::json;
use tungstenite::handshake::server::{Request, Response};
use tungstenite::{Message, WebSocket};

use crate::recording::{Channel, CHANNELS};

/// The WebSocket subprotocol of the Foxglove WebSocket protocol.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// The default address: localhost, Foxglove's default port.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";
/// Largest message a client may send, bytes.
pub const MAX_CLIENT_MESSAGE: usize = 64 * 1024;
/// Messages queued per client before it misses some.
const QUEUE: usize = 64;
/// Viewers served at once; more connections are closed right away.
pub const MAX_CLIENTS: usize = 16;
/// How long a client may take to send its WebSocket handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);
/// Binary opcode of a message.
const OP_MESSAGE_DATA: u8 = 0x01;

/// A message published on one channel.
struct Published {
    channel: Channel,
    /// Publication order (from 1), so that a subscriber sent the channel's latest message on
    /// subscribing never gets it, or an older one still queued, a second time.
    seq: u64,
    t_ns: u64,
    json: Vec<u8>,
}

/// State shared by the server's threads.
struct Shared {
    clients: Mutex<Vec<SyncSender<Arc<Published>>>>,
    latest: Mutex<[Option<Arc<Published>>; CHANNELS.len()]>,
    stop: AtomicBool,
    connections: AtomicU64,
    dropped: AtomicU64,
    published: AtomicU64,
}

/// A running live-view server; stops (and disconnects every client) when dropped.
pub struct LiveServer {
    addr: SocketAddr,
    shared: Arc<Shared>,
    accept: Option<JoinHandle<()>>,
}

impl LiveServer {
    /// Listens on `addr` (e.g. [`DEFAULT_ADDR`]; port 0 picks a free one).
    pub fn start(addr: &str) -> anyhow::Result<LiveServer> {
        let listener = TcpListener::bind(addr)
            .with_context(|| format!("--live {addr}: cannot listen there"))?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared {
            clients: Mutex::new(Vec::new()),
            latest: Mutex::new(Default::default()),
            stop: AtomicBool::new(false),
            connections: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            published: AtomicU64::new(0),
        });
        let s = shared.clone();
        let accept = std::thread::spawn(move || accept_loop(&listener, &s));
        Ok(LiveServer {
            addr,
            shared,
            accept: Some(accept),
        })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Clients that connected so far.
    pub fn connections(&self) -> u64 {
        self.shared.connections.load(Ordering::SeqCst)
    }

    /// Messages a slow client missed (its queue was full).
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::SeqCst)
    }

    /// Sends `message` on `channel` (host time `t_ns`) to every client subscribed to it, and
    /// keeps it as the channel's latest for clients that subscribe later.
    pub fn publish(&self, channel: Channel, t_ns: u64, message: &serde_json::Value) {
        let Ok(json) = serde_json::to_vec(message) else {
            return;
        };
        let seq = self.shared.published.fetch_add(1, Ordering::SeqCst) + 1;
        let p = Arc::new(Published {
            channel,
            seq,
            t_ns,
            json,
        });
        if let Some(slot) = lock(&self.shared.latest).get_mut(channel as usize) {
            *slot = Some(p.clone());
        }
        lock(&self.shared.clients).retain(|c| match c.try_send(p.clone()) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                self.shared.dropped.fetch_add(1, Ordering::SeqCst);
                true
            }
            Err(TrySendError::Disconnected(_)) => false,
        });
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        lock(&self.shared.clients).clear();
        if let Some(t) = self.accept.take() {
            let _ = t.join();
        }
    }
}

/// A poisoned lock still holds consistent data here (every critical section is one assignment
/// or one `retain`).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

fn accept_loop(listener: &TcpListener, shared: &Arc<Shared>) {
    let mut clients: Vec<JoinHandle<()>> = Vec::new();
    while !shared.stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((stream, _)) => {
                clients.retain(|c| !c.is_finished());
                if clients.len() >= MAX_CLIENTS {
                    // Dropping the stream closes it.
                    continue;
                }
                shared.connections.fetch_add(1, Ordering::SeqCst);
                let (tx, rx) = sync_channel(QUEUE);
                lock(&shared.clients).push(tx);
                let s = shared.clone();
                clients.push(std::thread::spawn(move || {
                    // A client's failure ends its connection only.
                    let _ = serve(stream, rx, &s);
                }));
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
        clients.retain(|c| !c.is_finished());
    }
    for c in clients {
        let _ = c.join();
    }
}

/// One client: the handshake (offering the subprotocol), `serverInfo` and `advertise`, then its
/// subscriptions and the messages published on them until it leaves or the server stops.
fn serve(stream: TcpStream, rx: Receiver<Arc<Published>>, shared: &Shared) -> anyhow::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(HANDSHAKE_TIMEOUT))?;
    stream.set_write_timeout(Some(Duration::from_secs(5)))?;
    let config = tungstenite::protocol::WebSocketConfig::default()
        .max_message_size(Some(MAX_CLIENT_MESSAGE))
        .max_frame_size(Some(MAX_CLIENT_MESSAGE));
    // The callback's error type is tungstenite's (an HTTP response); it never errs.
    #[allow(clippy::result_large_err)]
    let offer = |req: &Request, mut resp: Response| {
        let wanted = req
            .headers()
            .get_all("Sec-WebSocket-Protocol")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .any(|v| v.split(',').any(|p| p.trim() == SUBPROTOCOL));
        if wanted {
            if let Ok(v) = SUBPROTOCOL.parse() {
                resp.headers_mut().insert("Sec-WebSocket-Protocol", v);
            }
        }
        Ok(resp)
    };
    let mut ws = tungstenite::accept_hdr_with_config(stream, offer, Some(config))
        .map_err(|e| anyhow::anyhow!("handshake: {e}"))?;
    // From now on reads only poll: the loop also forwards what is published.
    ws.get_ref()
        .set_read_timeout(Some(Duration::from_millis(20)))?;
    ws.send(Message::text(server_info().to_string()))?;
    ws.send(Message::text(advertise().to_string()))?;
    // Subscription id → channel; the last message sent on it (publication order).
    let mut subs: BTreeMap<u32, Channel> = BTreeMap::new();
    let mut sent: BTreeMap<u32, u64> = BTreeMap::new();
    while !shared.stop.load(Ordering::SeqCst) {
        match ws.read() {
            Ok(Message::Text(t)) => {
                for (id, channel) in client_request(&t, &mut subs) {
                    // A new subscriber gets the channel's latest message at once.
                    let latest = lock(&shared.latest)
                        .get(channel as usize)
                        .cloned()
                        .flatten();
                    sent.insert(id, latest.as_ref().map_or(0, |p| p.seq));
                    if let Some(p) = latest {
                        send_message(&mut ws, id, &p)?;
                    }
                }
                sent.retain(|id, _| subs.contains_key(id));
            }
            Ok(Message::Close(_)) => return Ok(()),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(e) => return Err(e.into()),
        }
        while let Ok(p) = rx.try_recv() {
            let ids: Vec<u32> = subs
                .iter()
                .filter(|(id, &c)| c == p.channel && sent.get(id).is_some_and(|&s| s < p.seq))
                .map(|(&id, _)| id)
                .collect();
            for id in ids {
                sent.insert(id, p.seq);
                send_message(&mut ws, id, &p)?;
            }
        }
    }
    let _ = ws.close(None);
    Ok(())
}

fn send_message(ws: &mut WebSocket<TcpStream>, id: u32, p: &Published) -> anyhow::Result<()> {
    let mut frame = Vec::with_capacity(13 + p.json.len());
    frame.push(OP_MESSAGE_DATA);
    frame.extend_from_slice(&id.to_le_bytes());
    frame.extend_from_slice(&p.t_ns.to_le_bytes());
    frame.extend_from_slice(&p.json);
    ws.send(Message::binary(frame))?;
    Ok(())
}

/// Applies a client's text message to its subscriptions; returns the subscriptions it added.
/// Anything malformed, unknown or out of range is ignored.
fn client_request(text: &str, subs: &mut BTreeMap<u32, Channel>) -> Vec<(u32, Channel)> {
    let mut added = Vec::new();
    let Ok(v) = serde_json::from_str::<serde_json::Value>(text) else {
        return added;
    };
    let as_u32 = |v: &serde_json::Value| v.as_u64().and_then(|x| u32::try_from(x).ok());
    match v.get("op").and_then(|o| o.as_str()) {
        Some("subscribe") => {
            for s in v["subscriptions"].as_array().into_iter().flatten() {
                let (Some(id), Some(c)) = (as_u32(&s["id"]), as_u32(&s["channelId"])) else {
                    continue;
                };
                if let Some(channel) = channel_of_id(c) {
                    subs.insert(id, channel);
                    added.push((id, channel));
                }
            }
        }
        Some("unsubscribe") => {
            for id in v["subscriptionIds"].as_array().into_iter().flatten() {
                if let Some(id) = as_u32(id) {
                    subs.remove(&id);
                }
            }
        }
        _ => {}
    }
    added
}

/// Channel ids are 1-based positions in [`CHANNELS`].
fn channel_of_id(id: u32) -> Option<Channel> {
    match id {
        1 => Some(Channel::Marginals),
        2 => Some(Channel::LogOdds),
        3 => Some(Channel::Pose),
        4 => Some(Channel::Scan),
        _ => None,
    }
}

fn server_info() -> serde_json::Value {
    json!({
        "op": "serverInfo",
        "name": "host-sim listen",
        "capabilities": [],
        "supportedEncodings": [],
        "metadata": {},
        "sessionId": crate::recording::now_ns().to_string(),
    })
}

fn advertise() -> serde_json::Value {
    let channels: Vec<serde_json::Value> = CHANNELS
        .iter()
        .zip(1u32..)
        .map(|(c, id)| {
            json!({
                "id": id,
                "topic": c.topic,
                "encoding": "json",
                "schemaName": c.schema_name,
                "schema": c.schema,
                "schemaEncoding": "jsonschema",
            })
        })
        .collect();
    json!({"op": "advertise", "channels": channels})
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::{grid_message, pose_message, GridFrame};
    use tungstenite::client::IntoClientRequest;

    /// A Foxglove client's handshake request to `addr`.
    fn request(addr: SocketAddr) -> tungstenite::handshake::client::Request {
        let mut req = format!("ws://{addr}").into_client_request().unwrap();
        req.headers_mut()
            .insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse().unwrap());
        req
    }

    fn connect(addr: SocketAddr) -> WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>> {
        let (ws, resp) = tungstenite::connect(request(addr)).unwrap();
        assert_eq!(
            resp.headers()
                .get("Sec-WebSocket-Protocol")
                .and_then(|v| v.to_str().ok()),
            Some(SUBPROTOCOL)
        );
        ws
    }

    fn text(
        ws: &mut WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>,
    ) -> serde_json::Value {
        match ws.read().unwrap() {
            Message::Text(t) => serde_json::from_str(&t).unwrap(),
            m => panic!("expected text, got {m:?}"),
        }
    }

    /// The next binary message: subscription id, time, JSON.
    fn binary(
        ws: &mut WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>,
    ) -> (u32, u64, serde_json::Value) {
        loop {
            match ws.read().unwrap() {
                Message::Binary(b) => {
                    assert_eq!(b[0], OP_MESSAGE_DATA);
                    let id = u32::from_le_bytes(b[1..5].try_into().unwrap());
                    let t = u64::from_le_bytes(b[5..13].try_into().unwrap());
                    return (id, t, serde_json::from_slice(&b[13..]).unwrap());
                }
                Message::Ping(_) | Message::Pong(_) => {}
                m => panic!("expected binary, got {m:?}"),
            }
        }
    }

    #[test]
    fn foxglove_clients_get_the_channels_and_what_they_subscribed_to() {
        let server = LiveServer::start("127.0.0.1:0").unwrap();
        assert!(server.local_addr().ip().is_loopback());
        let cells = [Some(0.9), None, Some(0.1), Some(0.5), None, Some(1.0)];
        let frame = GridFrame {
            width: 3,
            height: 2,
            cell_m: 0.05,
            origin_m: (-1.0, 2.0),
            cells: &cells,
        };
        // Published before anyone connects: the latest is kept for later subscribers.
        server.publish(Channel::LogOdds, 7, &grid_message(&frame, 7));

        let mut ws = connect(server.local_addr());
        let info = text(&mut ws);
        assert_eq!(info["op"], "serverInfo");
        let adv = text(&mut ws);
        assert_eq!(adv["op"], "advertise");
        let chans = adv["channels"].as_array().unwrap();
        let topics: Vec<&str> = chans.iter().map(|c| c["topic"].as_str().unwrap()).collect();
        assert_eq!(
            topics,
            [
                "/map/marginals",
                "/map/log_odds",
                "/robot/pose",
                "/robot/scan"
            ]
        );
        assert!(chans
            .iter()
            .all(|c| c["encoding"] == "json" && c["schemaEncoding"] == "jsonschema"));

        // Garbage and bad requests are ignored, the connection stays.
        ws.send(Message::text("not json")).unwrap();
        ws.send(Message::text(
            r#"{"op":"subscribe","subscriptions":[{"id":-1,"channelId":99}]}"#,
        ))
        .unwrap();
        ws.send(Message::binary(vec![1, 2, 3])).unwrap();

        ws.send(Message::text(
            r#"{"op":"subscribe","subscriptions":[{"id":10,"channelId":2},{"id":11,"channelId":3}]}"#,
        ))
        .unwrap();
        // The log-odds map published before the subscription, at once.
        let (id, t, grid) = binary(&mut ws);
        assert_eq!((id, t), (10, 7));
        assert_eq!(grid["column_count"], 3);
        assert_eq!(grid["cell_size"]["x"], 0.05);
        assert_eq!(grid["pose"]["position"]["x"], -1.0);

        // Then what is published now, on the subscribed channels only.
        server.publish(Channel::Marginals, 8, &grid_message(&frame, 8));
        server.publish(Channel::Pose, 9, &pose_message(1.5, -0.5, 0.0, 9));
        let (id, t, pose) = binary(&mut ws);
        assert_eq!((id, t), (11, 9));
        assert_eq!(pose["pose"]["position"]["x"], 1.5);

        ws.send(Message::text(
            r#"{"op":"unsubscribe","subscriptionIds":[11]}"#,
        ))
        .unwrap();
        // A second client gets the same offer; the count includes it.
        let mut ws2 = connect(server.local_addr());
        assert_eq!(text(&mut ws2)["op"], "serverInfo");
        assert_eq!(server.connections(), 2);
        drop(server);
    }

    #[test]
    fn viewers_beyond_the_limit_are_turned_away() {
        let server = LiveServer::start("127.0.0.1:0").unwrap();
        let mut kept: Vec<_> = (0..MAX_CLIENTS)
            .map(|_| connect(server.local_addr()))
            .collect();
        for ws in &mut kept {
            assert_eq!(text(ws)["op"], "serverInfo");
        }
        assert!(
            tungstenite::connect(request(server.local_addr())).is_err(),
            "one viewer too many"
        );
        assert_eq!(server.connections(), MAX_CLIENTS as u64);
        // One leaves: a new one is served again.
        kept.pop().unwrap().close(None).unwrap();
        let t0 = std::time::Instant::now();
        loop {
            if tungstenite::connect(request(server.local_addr())).is_ok() {
                break;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(10),
                "no room after a viewer left"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    #[test]
    fn client_requests_are_parsed_defensively() {
        let mut subs = BTreeMap::new();
        for bad in [
            "",
            "[]",
            r#"{"op":1}"#,
            r#"{"op":"subscribe"}"#,
            r#"{"op":"subscribe","subscriptions":[{"id":"x","channelId":1}]}"#,
            r#"{"op":"subscribe","subscriptions":[{"id":4294967296,"channelId":1}]}"#,
            r#"{"op":"subscribe","subscriptions":[{"id":1,"channelId":0}]}"#,
            r#"{"op":"unsubscribe","subscriptionIds":"all"}"#,
        ] {
            assert!(client_request(bad, &mut subs).is_empty(), "{bad}");
        }
        assert!(subs.is_empty());
        let added = client_request(
            r#"{"op":"subscribe","subscriptions":[{"id":4294967295,"channelId":1}]}"#,
            &mut subs,
        );
        assert_eq!(added, [(u32::MAX, Channel::Marginals)]);
        client_request(
            r#"{"op":"unsubscribe","subscriptionIds":[4294967295]}"#,
            &mut subs,
        );
        assert!(subs.is_empty());
    }
}
