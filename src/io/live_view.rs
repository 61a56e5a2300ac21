//! The live view: a Foxglove WebSocket server (Foxglove's `foxglove`
//! crate) that streams the flight log's channels while the vehicle flies,
//! so that a ground station watches the estimate, its σ, the autopilot's
//! test ratios and the log lines as they happen (Foxglove: Open connection
//! ▸ Foxglove WebSocket, `ws://HOST:PORT`).
//!
//! Why it never slows the flight: the records are the ones the MCAP writer
//! already serialised, handed over on the writer's thread, not the fusion
//! loop's; and the server's send to each client is non-blocking and drops
//! the oldest messages of a client that cannot keep up. A channel with no
//! subscriber costs one atomic load. It is off unless `live_view.enabled`,
//! and listens on loopback unless configured otherwise.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;

use crate::io::mcap_log::{RecordTap, Topic};

/// Why the live view did not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveViewError {
    #[error("live_view.address '{address}': {message}")]
    Start { address: SocketAddr, message: String },
}

/// The channels, as the MCAP writer's thread logs to them. Cheap to clone.
#[derive(Clone)]
pub struct LiveSink {
    channels: Arc<BTreeMap<Topic, Arc<foxglove::RawChannel>>>,
}

impl RecordTap for LiveSink {
    /// Sends one record (its JSON as the log has it) to the clients
    /// subscribed to its channel; never blocks.
    fn record(&self, topic: Topic, log_time_ns: u64, json: &[u8]) {
        if let Some(c) = self.channels.get(&topic) {
            if c.has_sinks() {
                c.log_with_meta(json, foxglove::PartialMetadata::with_log_time(log_time_ns));
            }
        }
    }
}

/// The running server.
pub struct LiveView {
    /// The context owns the channels (they hold it weakly).
    _context: Arc<foxglove::Context>,
    sink: LiveSink,
    server: foxglove::WebSocketServerHandle,
}

impl LiveView {
    /// Starts the server on `address`, with one channel per log topic (the
    /// same topic names and JSON schemas as the MCAP log).
    pub async fn start(address: SocketAddr) -> Result<Self, LiveViewError> {
        let err = |message: String| LiveViewError::Start { address, message };
        let context = foxglove::Context::new();
        let mut channels = BTreeMap::new();
        for t in Topic::ALL {
            let (topic, schema_name, schema) = t.spec();
            let c = context
                .channel_builder(topic)
                .message_encoding("json")
                .schema(foxglove::Schema::new(schema_name, "jsonschema", schema.as_bytes()))
                .build_raw()
                .map_err(|e| err(e.to_string()))?;
            channels.insert(t, c);
        }
        let server = context
            .websocket_server()
            .name("cmsckf")
            .bind(address.ip().to_string(), address.port())
            .start()
            .await
            .map_err(|e| err(e.to_string()))?;
        tracing::info!(address = %address, port = server.port(), "live view: Foxglove WebSocket server listening");
        Ok(Self {
            _context: context,
            sink: LiveSink {
                channels: Arc::new(channels),
            },
            server,
        })
    }

    /// The port it listens on (the one asked for, or the one given for 0).
    pub fn port(&self) -> u16 {
        self.server.port()
    }

    /// What the log writer sends through.
    pub fn sink(&self) -> LiveSink {
        self.sink.clone()
    }

    /// Stops the server and closes its clients.
    pub async fn stop(self) {
        self.server.stop().wait().await;
    }
}
