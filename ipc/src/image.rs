//! Camera images as dynamic `[u8]` slices with a small header, so a 640×480 RGB frame is written once into
//! shared memory and read in place by the controller.

use iceoryx2::prelude::ZeroCopySend;

use crate::schema::SCHEMA_VERSION;

/// Pixel layout of an image payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ImageEncoding {
    Rgb8 = 1,
    Bgr8 = 2,
    Mono8 = 3,
}

impl ImageEncoding {
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Rgb8),
            2 => Some(Self::Bgr8),
            3 => Some(Self::Mono8),
            _ => None,
        }
    }

    /// The name configs and command lines use: `rgb8`, `bgr8`, `mono8` (as ROS's sensor_msgs/Image does).
    pub fn name(self) -> &'static str {
        match self {
            Self::Rgb8 => "rgb8",
            Self::Bgr8 => "bgr8",
            Self::Mono8 => "mono8",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Rgb8, Self::Bgr8, Self::Mono8].into_iter().find(|e| e.name() == name)
    }

    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Self::Rgb8 | Self::Bgr8 => 3,
            Self::Mono8 => 1,
        }
    }
}

/// The user header of an image frame; it also carries the schema version (images have no other header).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("mars::ImageHeader")]
#[repr(C)]
pub struct ImageHeader {
    pub schema_version: u32,
    pub width: u32,
    pub height: u32,
    /// An [`ImageEncoding`] as `u32`.
    pub encoding: u32,
    pub seq: u64,
    /// CLOCK_MONOTONIC of the exposure, in ns.
    pub timestamp_ns: u64,
}

impl Default for ImageHeader {
    fn default() -> Self {
        Self { schema_version: SCHEMA_VERSION, width: 0, height: 0, encoding: 0, seq: 0, timestamp_ns: 0 }
    }
}

impl ImageHeader {
    /// Bytes the payload must have; `None` for an unknown encoding or an overflowing size.
    pub fn expected_len(&self) -> Option<usize> {
        let bpp = ImageEncoding::from_u32(self.encoding)?.bytes_per_pixel();
        (self.width as usize).checked_mul(self.height as usize)?.checked_mul(bpp)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expected_len_follows_encoding() {
        let h = ImageHeader { width: 640, height: 480, encoding: ImageEncoding::Rgb8 as u32, ..Default::default() };
        assert_eq!(h.expected_len(), Some(640 * 480 * 3));
        let h = ImageHeader { encoding: ImageEncoding::Mono8 as u32, ..h };
        assert_eq!(h.expected_len(), Some(640 * 480));
        assert_eq!(ImageHeader { encoding: 9, ..h }.expected_len(), None);
    }

    #[test]
    fn encodings_round_trip_through_their_names() {
        for e in [ImageEncoding::Rgb8, ImageEncoding::Bgr8, ImageEncoding::Mono8] {
            assert_eq!(ImageEncoding::from_name(e.name()), Some(e));
            assert_eq!(ImageEncoding::from_u32(e as u32), Some(e));
        }
        assert_eq!(ImageEncoding::from_name("RGB"), None);
    }
}
