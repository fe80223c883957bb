//! Typed ports for the kinds of frame: state, command, camera images, the scene's state and requests, and a
//! daemon's live statistics.
//!
//! Both sides open every service through the functions here, so the quality-of-service settings they pass to
//! iceoryx2 are identical by construction (iceoryx2 refuses to open a service with incompatible settings).
//! Readers check the schema version of every frame and hand out [`WireError::Schema`] instead of a frame from
//! a mismatched build.

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;

use crate::command::JointCommand;
use crate::image::ImageHeader;
use crate::live::LiveStats;
use crate::names::{NameError, RobotNamespace};
use crate::scene::{SceneRequest, SceneState};
use crate::schema::{FrameHeader, SchemaMismatch, check_schema_version};
use crate::state::RobotState;

/// Frames a subscriber keeps before the oldest is overwritten. At 1 kHz this is 16 ms of backlog: a reader
/// that falls further behind wants the newest frames anyway.
const BUFFER: usize = 16;
/// Room for a restarted controller while a dead one's ports are still registered, plus monitoring tools.
const MAX_PORTS: usize = 8;
const MAX_NODES: usize = 16;

#[derive(Debug, thiserror::Error)]
pub enum WireError {
    #[error(transparent)]
    Name(#[from] NameError),
    #[error("iceoryx2 node: {0}")]
    Node(String),
    #[error("iceoryx2 service {service:?}: {reason}")]
    Service { service: String, reason: String },
    #[error("iceoryx2 port on {service:?}: {reason}")]
    Port { service: String, reason: String },
    #[error("refused a frame on {service:?}: {mismatch}")]
    Schema { service: String, mismatch: SchemaMismatch },
    #[error("refused an image on {service:?}: header says {expected:?} bytes, payload has {found}")]
    BadImage { service: String, expected: Option<usize>, found: usize },
}

/// Why a frame could not be received: `Copy` and allocation-free, since real-time loops call `receive` every
/// tick and must be able to count and classify a failure without touching the heap. The service is known to
/// the caller (it owns the reader).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameReceiveError {
    /// A frame from a build with another schema version (consumed; the next call goes on).
    #[error("{0}")]
    Schema(SchemaMismatch),
    /// iceoryx2 could not hand out a frame (too many held, or the connection to a publisher failed).
    #[error("iceoryx2 receive failed: {0}")]
    Port(iceoryx2::port::ReceiveError),
}

/// Why an image could not be received: `Copy` and allocation-free, like [`FrameReceiveError`], so a camera
/// reader can count and classify a bad frame without touching the heap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ImageReceiveError {
    /// An image from a build (or a publisher in another language) with another schema version.
    #[error("{0}")]
    Schema(SchemaMismatch),
    /// The payload's length is not what the header's width, height and encoding make (or the encoding is unknown,
    /// `expected` = None): the pixels cannot be read safely.
    #[error(
        "the header says {width}×{height}, encoding {encoding}: {} bytes, but the payload has {found}",
        expected.map_or("an unknown number of".to_string(), |e| e.to_string())
    )]
    Length { width: u32, height: u32, encoding: u32, expected: Option<usize>, found: usize },
    /// iceoryx2 could not hand out a frame.
    #[error("iceoryx2 receive failed: {0}")]
    Port(iceoryx2::port::ReceiveError),
}

/// Why a frame could not be sent: `Copy` and allocation-free, like [`FrameReceiveError`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameSendError {
    #[error("iceoryx2 loan failed: {0}")]
    Loan(iceoryx2::port::LoanError),
    #[error("iceoryx2 send failed: {0}")]
    Send(iceoryx2::port::SendError),
}

fn svc_err(service: &ServiceName, e: impl core::fmt::Debug) -> WireError {
    WireError::Service { service: service.as_str().to_owned(), reason: format!("{e:?}") }
}

fn port_err(service: &ServiceName, e: impl core::fmt::Debug) -> WireError {
    WireError::Port { service: service.as_str().to_owned(), reason: format!("{e:?}") }
}

/// What opening a service yields: its name (for errors) and its port factory.
type Opened<T, H> = (ServiceName, iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, H>);

type FramePublisher<T> = Publisher<ipc::Service, T, FrameHeader>;
type FrameSubscriber<T> = Subscriber<ipc::Service, T, FrameHeader>;

macro_rules! frame_ports {
    ($writer:ident, $reader:ident, $payload:ty, $name_fn:ident) => {
        fn $name_fn(
            node: &Node<ipc::Service>,
            ns: &RobotNamespace,
        ) -> Result<
            (
                ServiceName,
                iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, $payload, FrameHeader>,
            ),
            WireError,
        > {
            let name = ns.$name_fn()?;
            let service = node
                .service_builder(&name)
                .publish_subscribe::<$payload>()
                .user_header::<FrameHeader>()
                .subscriber_max_buffer_size(BUFFER)
                .history_size(0)
                .max_publishers(MAX_PORTS)
                .max_subscribers(MAX_PORTS)
                .max_nodes(MAX_NODES)
                .open_or_create()
                .map_err(|e| svc_err(&name, e))?;
            Ok((name, service))
        }

        /// Publishes frames stamped with this build's schema version.
        pub struct $writer {
            name: ServiceName,
            publisher: FramePublisher<$payload>,
        }

        impl $writer {
            pub fn new(node: &Node<ipc::Service>, ns: &RobotNamespace) -> Result<Self, WireError> {
                let (name, service) = $name_fn(node, ns)?;
                let publisher = service.publisher_builder().create().map_err(|e| port_err(&name, e))?;
                Ok(Self { name, publisher })
            }

            /// Write `frame` straight into shared memory and deliver it; returns how many readers got it.
            pub fn send(&self, frame: &$payload) -> Result<usize, FrameSendError> {
                self.send_with_header(frame, FrameHeader::default())
            }

            /// [`Self::send`] with an explicit header: only for exercising the receivers' refusal path.
            pub fn send_with_header(&self, frame: &$payload, header: FrameHeader) -> Result<usize, FrameSendError> {
                let mut sample = self.publisher.loan_uninit().map_err(FrameSendError::Loan)?;
                *sample.user_header_mut() = header;
                sample.write_payload(*frame).send().map_err(FrameSendError::Send)
            }

            /// The service this writer publishes on (for error messages outside the real-time path).
            pub fn service(&self) -> &str {
                self.name.as_str()
            }
        }

        /// Receives frames and refuses those of another schema version.
        pub struct $reader {
            name: ServiceName,
            subscriber: FrameSubscriber<$payload>,
        }

        impl $reader {
            pub fn new(node: &Node<ipc::Service>, ns: &RobotNamespace) -> Result<Self, WireError> {
                let (name, service) = $name_fn(node, ns)?;
                let subscriber =
                    service.subscriber_builder().buffer_size(BUFFER).create().map_err(|e| port_err(&name, e))?;
                Ok(Self { name, subscriber })
            }

            /// The next frame, `Ok(None)` when none is waiting, or [`FrameReceiveError::Schema`] for a frame
            /// from a mismatched build (that frame is consumed; the next call goes on with the following one).
            /// Allocates nothing of ours, also not on an error; iceoryx2 itself allocates once when a new publisher
            /// has appeared since the last call (it sets up the connection: the loops count from after that).
            pub fn receive(&self) -> Result<Option<$payload>, FrameReceiveError> {
                let Some(sample) = self.subscriber.receive().map_err(FrameReceiveError::Port)? else {
                    return Ok(None);
                };
                check_schema_version(sample.user_header().schema_version).map_err(FrameReceiveError::Schema)?;
                Ok(Some(*sample.payload()))
            }

            /// The service this reader subscribes to (for error messages outside the real-time path).
            pub fn service(&self) -> &str {
                self.name.as_str()
            }
        }
    };
}

frame_ports!(StateWriter, StateReader, RobotState, state);
frame_ports!(CommandWriter, CommandReader, JointCommand, command);
frame_ports!(SceneStateWriter, SceneStateReader, SceneState, scene_state);
frame_ports!(SceneRequestWriter, SceneRequestReader, SceneRequest, scene_request);
frame_ports!(LiveWriter, LiveReader, LiveStats, live);

fn image_service(
    node: &Node<ipc::Service>,
    ns: &RobotNamespace,
    camera: &str,
) -> Result<Opened<[u8], ImageHeader>, WireError> {
    let name = ns.camera(camera)?;
    let service = node
        .service_builder(&name)
        .publish_subscribe::<[u8]>()
        .user_header::<ImageHeader>()
        .subscriber_max_buffer_size(2)
        .history_size(0)
        .max_publishers(2)
        .max_subscribers(MAX_PORTS)
        .max_nodes(MAX_NODES)
        .open_or_create()
        .map_err(|e| svc_err(&name, e))?;
    Ok((name, service))
}

/// Publishes camera frames as `[u8]` slices written in place in shared memory.
pub struct ImageWriter {
    name: ServiceName,
    publisher: Publisher<ipc::Service, [u8], ImageHeader>,
}

impl ImageWriter {
    /// `max_len`: the largest frame expected (e.g. 640·480·3); a larger one grows the pool (power of two).
    pub fn new(
        node: &Node<ipc::Service>,
        ns: &RobotNamespace,
        camera: &str,
        max_len: usize,
    ) -> Result<Self, WireError> {
        let (name, service) = image_service(node, ns, camera)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(max_len)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| port_err(&name, e))?;
        Ok(Self { name, publisher })
    }

    /// Loan `header.expected_len()` bytes of shared memory, let `fill` write the pixels there, and deliver.
    pub fn send_with(&self, header: ImageHeader, fill: impl FnOnce(&mut [u8])) -> Result<usize, WireError> {
        let len = header.expected_len().ok_or(WireError::BadImage {
            service: self.name.as_str().to_owned(),
            expected: None,
            found: 0,
        })?;
        self.send_raw(header, len, fill)
    }

    /// [`Self::send_with`] with a payload of `len` bytes whatever the header says: only for exercising the
    /// readers' refusal path (a camera process with a bug, or in another language, can send such a frame).
    pub fn send_raw(&self, header: ImageHeader, len: usize, fill: impl FnOnce(&mut [u8])) -> Result<usize, WireError> {
        let mut sample = self.publisher.loan_slice_uninit(len).map_err(|e| port_err(&self.name, e))?;
        *sample.user_header_mut() = header;
        for b in sample.payload_mut() {
            b.write(0);
        }
        // SAFETY: every byte of the payload was written just above.
        let mut sample = unsafe { sample.assume_init() };
        fill(sample.payload_mut());
        sample.send().map_err(|e| port_err(&self.name, e))
    }
}

/// A received image: a view into shared memory, released when dropped.
pub struct ImageFrame {
    sample: Sample<ipc::Service, [u8], ImageHeader>,
}

impl ImageFrame {
    pub fn header(&self) -> &ImageHeader {
        self.sample.user_header()
    }

    pub fn pixels(&self) -> &[u8] {
        self.sample.payload()
    }
}

/// Whether a received image of header `h` and a payload of `found` bytes may be read: this build's schema, and
/// exactly the bytes the header's size and encoding make. Allocation-free.
pub fn check_image(h: &ImageHeader, found: usize) -> Result<(), ImageReceiveError> {
    check_schema_version(h.schema_version).map_err(ImageReceiveError::Schema)?;
    let expected = h.expected_len();
    if expected != Some(found) {
        return Err(ImageReceiveError::Length {
            width: h.width,
            height: h.height,
            encoding: h.encoding,
            expected,
            found,
        });
    }
    Ok(())
}

pub struct ImageReader {
    name: ServiceName,
    subscriber: Subscriber<ipc::Service, [u8], ImageHeader>,
}

impl ImageReader {
    pub fn new(node: &Node<ipc::Service>, ns: &RobotNamespace, camera: &str) -> Result<Self, WireError> {
        let (name, service) = image_service(node, ns, camera)?;
        let subscriber = service.subscriber_builder().buffer_size(2).create().map_err(|e| port_err(&name, e))?;
        Ok(Self { name, subscriber })
    }

    /// The next image, or why the frame must not be read (that frame is consumed; the next call goes on with the
    /// following one). Allocation-free, also on an error.
    pub fn receive(&self) -> Result<Option<ImageFrame>, ImageReceiveError> {
        let Some(sample) = self.subscriber.receive().map_err(ImageReceiveError::Port)? else {
            return Ok(None);
        };
        check_image(sample.user_header(), sample.payload().len())?;
        Ok(Some(ImageFrame { sample }))
    }

    /// The service this reader subscribes to (for error messages outside the real-time path).
    pub fn service(&self) -> &str {
        self.name.as_str()
    }
}
