//! How a backend answers the streams the renderer asks ([`super::Backend`]'s
//! `*_stream` queries): one ray at a time, or packets of neighbouring rays
//! traversed together, or Embree 3's stream API. Every path gives the answers
//! the backend's single-ray queries give; only the speed differs.

use std::str::FromStr;

/// A query path (`--query`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Query {
    /// One ray at a time (`rtcIntersect1`/`rtcOccluded1` for Embree).
    Single,
    /// Packets of `N` consecutive rays of the stream (`rtcIntersect{N}` for
    /// Embree with N = 4, 8 or 16; raylab's own packet traversal of the 8-wide
    /// tree with N = 8).
    Packet(usize),
    /// Embree 3's stream API over the whole stream (`rtcIntersect1M`).
    Stream,
    /// Embree's packets of `N` rays (4, 8 or 16) marked incoherent
    /// (`RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT`) instead of coherent: its
    /// faster path for scattered rays, and on some scenes for shadow, AO
    /// and even primary rays (docs/results.md). Embree 4 takes no hint from
    /// raylab (null arguments: its default, incoherent), so there it is the
    /// same call as `Packet`.
    IncoherentPacket(usize),
}

impl Query {
    /// Every path some backend has, in the order reports list them.
    pub const ALL: [Query; 8] = [
        Query::Single,
        Query::Packet(4),
        Query::Packet(8),
        Query::Packet(16),
        Query::Stream,
        Query::IncoherentPacket(4),
        Query::IncoherentPacket(8),
        Query::IncoherentPacket(16),
    ];

    /// `single`, `packet8`, `stream`, `packet16-incoherent`.
    pub fn name(self) -> String {
        match self {
            Query::Single => "single".into(),
            Query::Packet(n) => format!("packet{n}"),
            Query::Stream => "stream".into(),
            Query::IncoherentPacket(n) => format!("packet{n}-incoherent"),
        }
    }
}

impl std::fmt::Display for Query {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

impl FromStr for Query {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Query::ALL
            .into_iter()
            .find(|q| q.name() == s)
            .ok_or_else(|| {
                format!("'{s}': expected single, packet4, packet8, packet16, stream or packetN-incoherent (N = 4, 8, 16)")
            })
    }
}
