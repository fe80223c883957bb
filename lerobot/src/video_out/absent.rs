//! A build without FFmpeg: the writer's video types exist, but none can be created.

use std::path::Path;

use crate::LeRobotError;
use crate::video::NO_VIDEO;

/// No value of this type exists: the methods below cannot be called.
enum Never {}

pub struct VideoWriter {
    never: Never,
    pub codec: &'static str,
}

impl VideoWriter {
    pub fn create(path: &Path, _width: u32, _height: u32, _fps: u32) -> Result<Self, LeRobotError> {
        Err(LeRobotError::video(path, NO_VIDEO))
    }

    pub fn frames(&self) -> i64 {
        match self.never {}
    }

    pub fn push(&mut self, _rgb: &[u8]) -> Result<(), LeRobotError> {
        match self.never {}
    }

    pub fn finish(self) -> Result<(), LeRobotError> {
        match self.never {}
    }
}

pub struct VideoFile {
    never: Never,
}

impl VideoFile {
    pub fn create(path: &Path, _episode: &Path, _fps: u32) -> Result<Self, LeRobotError> {
        Err(LeRobotError::video(path, NO_VIDEO))
    }

    pub fn frames(&self) -> i64 {
        match self.never {}
    }

    pub fn bytes(&self) -> u64 {
        match self.never {}
    }

    pub fn append(&mut self, _episode: &Path, _frames: i64) -> Result<(), LeRobotError> {
        match self.never {}
    }

    pub fn finish(self) -> Result<(), LeRobotError> {
        match self.never {}
    }
}
