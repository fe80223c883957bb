//! The two messages, as bytes: a [`Request`] goes up (observation, history, the time the robot can wait), a
//! [`Reply`] comes down (the chunk, tagged with the request's seq, and how the host spent the time).
//!
//! Little-endian, fixed header then `f32` arrays, a magic and a version first: a Python client reads it with
//! `struct` and `numpy.frombuffer`. Decoding checks every length against what the bytes hold and refuses
//! non-finite values, so no payload a peer sends can panic or exhaust memory here.

/// "MARQ": a request.
pub const REQUEST_MAGIC: [u8; 4] = *b"MARQ";
/// "MARP": a reply.
pub const REPLY_MAGIC: [u8; 4] = *b"MARP";
/// Bumped on any change of either layout.
pub const VERSION: u16 = 2;
/// The most `f32` values one array may hold (16 MiB): a 4-camera 224 px observation fits, a corrupt length does not.
pub const MAX_VALUES: usize = 1 << 22;

const REQUEST_HEADER: usize = 4 + 2 + 2 + 7 * 8 + 3 * 4;
const REPLY_HEADER: usize = 4 + 2 + 2 + 3 * 8 + 2 * 4 + 4 + 8 + 4 + 4;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error("{what}: {got} bytes, shorter than its header ({want})")]
    Short { what: &'static str, got: usize, want: usize },
    #[error("{what}: magic {got:?}, not {want:?}")]
    Magic { what: &'static str, got: [u8; 4], want: [u8; 4] },
    #[error("{what}: wire version {got}, this build speaks {VERSION}")]
    Version { what: &'static str, got: u16 },
    #[error("{what}: {array} holds {got} values, more than the {MAX_VALUES} allowed")]
    TooLong { what: &'static str, array: &'static str, got: u64 },
    #[error("{what}: the header announces {want} bytes, the message has {got}")]
    Length { what: &'static str, got: usize, want: u64 },
    #[error("{what}: {array}[{index}] is {value}, not a finite number")]
    NonFinite { what: &'static str, array: &'static str, index: usize, value: f32 },
    #[error("reply: status {0} is not one this build knows")]
    Status(u16),
}

/// What the robot asks for: the chunk after `history` for `observation`, back within `budget_ns`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Request {
    /// Increases with every request of a robot; the reply carries it back.
    pub seq: u64,
    pub episode: u64,
    /// The policy period the chunk starts at (the engine's call seed is derived from it, as in a local run).
    pub period: u64,
    /// When the observation was captured, on the robot's CLOCK_MONOTONIC.
    pub capture_ns: u64,
    /// When the request left, on the robot's clock.
    pub sent_ns: u64,
    /// How long the host may take from receiving it to sending the reply: the robot's time left, less its
    /// handoff margin and the measured round trip. The host's deadline is its own receive time plus this, so
    /// no clock needs to agree with another for the scheduling.
    pub budget_ns: u64,
    /// The engine's noise seed for this call.
    pub seed: u64,
    pub observation: Vec<f32>,
    /// The last chunk of actions executed or in force, oldest first (C·D values).
    pub history: Vec<f32>,
    /// The chunk's first rows as the robot will have executed them from the previous chunk when this one arrives
    /// (whole rows, fewer than C; empty when the robot asks no earlier than the chunk is needed): the host's call is
    /// guided toward them (`mars_engine::Engine::infer_after`).
    pub committed: Vec<f32>,
}

/// How the host answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u16)]
pub enum Status {
    /// A chunk.
    #[default]
    Chunk = 0,
    /// Its deadline had passed when the host came to it: dropped unrun (the robot has moved on).
    Expired = 1,
    /// The engine refused the inputs (lengths, non-finite values); the message says which.
    Refused = 2,
    /// No policy is served for this robot here.
    UnknownRobot = 3,
}

impl Status {
    fn from_u16(v: u16) -> Result<Self, WireError> {
        Ok(match v {
            0 => Self::Chunk,
            1 => Self::Expired,
            2 => Self::Refused,
            3 => Self::UnknownRobot,
            other => return Err(WireError::Status(other)),
        })
    }
}

/// The host's answer to one [`Request`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Reply {
    pub status: Status,
    /// The request's seq.
    pub seq: u64,
    /// When the request arrived and when the reply left, on the host's clock.
    pub received_ns: u64,
    pub sent_ns: u64,
    pub k_requested: u32,
    pub k_used: u32,
    /// The deadline cut the steps; not even one step fitted (one ran anyway).
    pub capped: bool,
    pub over_budget: bool,
    pub encode_ns: u64,
    /// max |w| of the call.
    pub w_inf: f32,
    /// The chunk [C, D] in task units (empty unless `status` is `Chunk`).
    pub chunk: Vec<f32>,
}

impl Request {
    /// The message's bytes, appended to `out` (cleared first), so a caller reuses one buffer.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        out.clear();
        out.reserve(REQUEST_HEADER + 4 * (self.observation.len() + self.history.len() + self.committed.len()));
        out.extend_from_slice(&REQUEST_MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        for v in [self.seq, self.episode, self.period, self.capture_ns, self.sent_ns, self.budget_ns, self.seed] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&(self.observation.len() as u32).to_le_bytes());
        out.extend_from_slice(&(self.history.len() as u32).to_le_bytes());
        out.extend_from_slice(&(self.committed.len() as u32).to_le_bytes());
        put_f32s(out, &self.observation);
        put_f32s(out, &self.history);
        put_f32s(out, &self.committed);
    }

    pub fn decode(bytes: &[u8]) -> Result<Self, WireError> {
        const WHAT: &str = "request";
        let mut r = Reader::new(WHAT, bytes, REQUEST_HEADER, REQUEST_MAGIC)?;
        let _flags = r.u16();
        let [seq, episode, period, capture_ns, sent_ns, budget_ns, seed] = std::array::from_fn(|_| r.u64());
        let (n_obs, n_hist, n_committed) = (r.u32(), r.u32(), r.u32());
        r.expect_values(&[("observation", n_obs), ("history", n_hist), ("committed", n_committed)])?;
        let observation = r.f32s("observation", n_obs as usize)?;
        let history = r.f32s("history", n_hist as usize)?;
        let committed = r.f32s("committed", n_committed as usize)?;
        Ok(Self { seq, episode, period, capture_ns, sent_ns, budget_ns, seed, observation, history, committed })
    }
}

impl Reply {
    /// A reply without a chunk (`Expired`, `Refused`, `UnknownRobot`).
    pub fn without_chunk(status: Status, seq: u64, received_ns: u64) -> Self {
        Self { status, seq, received_ns, ..Default::default() }
    }

    pub fn encode_into(&self, out: &mut Vec<u8>) {
        out.clear();
        out.reserve(REPLY_HEADER + 4 * self.chunk.len());
        out.extend_from_slice(&REPLY_MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&(self.status as u16).to_le_bytes());
        for v in [self.seq, self.received_ns, self.sent_ns] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&self.k_requested.to_le_bytes());
        out.extend_from_slice(&self.k_used.to_le_bytes());
        let flags = u32::from(self.capped) | (u32::from(self.over_budget) << 1);
        out.extend_from_slice(&flags.to_le_bytes());
        out.extend_from_slice(&self.encode_ns.to_le_bytes());
        out.extend_from_slice(&self.w_inf.to_le_bytes());
        out.extend_from_slice(&(self.chunk.len() as u32).to_le_bytes());
        put_f32s(out, &self.chunk);
    }

    pub fn decode(bytes: &[u8]) -> Result<Self, WireError> {
        const WHAT: &str = "reply";
        let mut r = Reader::new(WHAT, bytes, REPLY_HEADER, REPLY_MAGIC)?;
        let status = Status::from_u16(r.u16())?;
        let [seq, received_ns, sent_ns] = std::array::from_fn(|_| r.u64());
        let (k_requested, k_used, flags) = (r.u32(), r.u32(), r.u32());
        let encode_ns = r.u64();
        let w_inf = f32::from_bits(r.u32());
        let n = r.u32();
        r.expect_values(&[("chunk", n)])?;
        let chunk = r.f32s("chunk", n as usize)?;
        Ok(Self {
            status,
            seq,
            received_ns,
            sent_ns,
            k_requested,
            k_used,
            capped: flags & 1 != 0,
            over_budget: flags & 2 != 0,
            encode_ns,
            w_inf,
            chunk,
        })
    }
}

fn put_f32s(out: &mut Vec<u8>, values: &[f32]) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// Reads a message whose header length is already checked; the arrays are checked before they are read.
struct Reader<'a> {
    what: &'static str,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn new(what: &'static str, bytes: &'a [u8], header: usize, magic: [u8; 4]) -> Result<Self, WireError> {
        if bytes.len() < header {
            return Err(WireError::Short { what, got: bytes.len(), want: header });
        }
        let got: [u8; 4] = [bytes[0], bytes[1], bytes[2], bytes[3]];
        if got != magic {
            return Err(WireError::Magic { what, got, want: magic });
        }
        let mut r = Self { what, bytes, at: 4 };
        match r.u16() {
            VERSION => Ok(r),
            got => Err(WireError::Version { what, got }),
        }
    }

    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.bytes[self.at..self.at + N]);
        self.at += N;
        a
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }

    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }

    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }

    /// The header is read: the arrays announced must each be within [`MAX_VALUES`] and fill the rest exactly.
    fn expect_values(&self, arrays: &[(&'static str, u32)]) -> Result<(), WireError> {
        let what = self.what;
        for &(array, n) in arrays {
            if n as usize > MAX_VALUES {
                return Err(WireError::TooLong { what, array, got: u64::from(n) });
            }
        }
        let values: u64 = arrays.iter().map(|&(_, n)| u64::from(n)).sum();
        let want = self.at as u64 + 4 * values;
        if want != self.bytes.len() as u64 {
            return Err(WireError::Length { what, got: self.bytes.len(), want });
        }
        Ok(())
    }

    fn f32s(&mut self, array: &'static str, n: usize) -> Result<Vec<f32>, WireError> {
        let mut v = Vec::with_capacity(n);
        for index in 0..n {
            let value = f32::from_le_bytes(self.take());
            if !value.is_finite() {
                return Err(WireError::NonFinite { what: self.what, array, index, value });
            }
            v.push(value);
        }
        Ok(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request() -> Request {
        Request {
            seq: 7,
            episode: 2,
            period: 48,
            capture_ns: 1_000,
            sent_ns: 2_000,
            budget_ns: 30_000_000,
            seed: 99,
            observation: vec![0.5, -1.0, 3.25],
            history: vec![1.0; 16],
            committed: vec![0.5; 4],
        }
    }

    #[test]
    fn both_messages_come_back_as_they_were_sent() {
        let mut bytes = Vec::new();
        request().encode_into(&mut bytes);
        assert_eq!(Request::decode(&bytes), Ok(request()));
        let reply = Reply {
            status: Status::Chunk,
            seq: 7,
            received_ns: 5,
            sent_ns: 9,
            k_requested: 4,
            k_used: 3,
            capped: true,
            over_budget: false,
            encode_ns: 120_000,
            w_inf: 0.4,
            chunk: vec![0.25; 16],
        };
        reply.encode_into(&mut bytes);
        assert_eq!(Reply::decode(&bytes), Ok(reply));
    }

    #[test]
    fn every_cut_or_corrupt_message_is_refused_with_a_reason() {
        let mut bytes = Vec::new();
        request().encode_into(&mut bytes);
        for cut in 0..bytes.len() {
            assert!(Request::decode(&bytes[..cut]).is_err(), "a request cut at {cut} bytes was accepted");
        }
        let mut long = bytes.clone();
        long[REQUEST_HEADER - 12..REQUEST_HEADER - 8].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(Request::decode(&long), Err(WireError::TooLong { array: "observation", .. })));
        let mut nan = bytes.clone();
        nan[REQUEST_HEADER + 4..REQUEST_HEADER + 8].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(matches!(Request::decode(&nan), Err(WireError::NonFinite { index: 1, .. })));
        let mut version = bytes.clone();
        version[4] = 9;
        assert_eq!(Request::decode(&version), Err(WireError::Version { what: "request", got: 9 }));
        assert!(matches!(Reply::decode(&bytes), Err(WireError::Magic { .. })));
    }
}
