//! Error values of the core. Each says what is wrong in one line (`Display`) and never carries a heap allocation.

use core::fmt;

/// Why a frame was rejected. A rejected frame changes no state of the mapper.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Width or height is zero.
    EmptyFrame,
    /// The frame has more pixels than the capacity profile was built for.
    TooLarge {
        /// Pixels in the frame.
        pixels: usize,
        /// Largest frame (pixels) of the profile.
        max_pixels: usize,
    },
    /// The depth buffer does not hold `width × height` samples.
    DepthLength {
        /// Expected number of `u16` samples.
        expected: usize,
        /// Samples found.
        found: usize,
    },
    /// The colour buffer does not hold `width × height × 3` bytes (packed RGB).
    ColourLength {
        /// Expected bytes.
        expected: usize,
        /// Bytes found.
        found: usize,
    },
    /// A focal length is zero, negative or not finite, or a principal point is not finite.
    BadIntrinsics,
    /// The depth scale (raw units per metre) is zero, negative or not finite.
    BadDepthScale,
    /// The camera pose is not finite or its rotation is not a proper orthonormal matrix.
    BadPose,
    /// No depth sample lies inside `[depth_min, depth_max]`.
    NoValidDepth,
    /// Every valid depth sample has the same raw value: a stuck or saturated sensor, not a scene.
    ConstantDepth {
        /// The one raw value seen.
        raw: u16,
    },
    /// The instance masks are malformed.
    Masks(MaskError),
}

/// Why an instance-mask set was rejected.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MaskError {
    /// The mask image size differs from the frame size.
    SizeMismatch {
        /// Mask width and height, pixels.
        mask: (u16, u16),
        /// Frame width and height, pixels.
        frame: (u16, u16),
    },
    /// The pixel buffer has the wrong length for the size and layout.
    PixelLength {
        /// Expected length, elements.
        expected: usize,
        /// Length found.
        found: usize,
    },
    /// An instance score is outside `[0, 1]` or not finite.
    BadScore {
        /// Instance id.
        id: u16,
    },
    /// An instance bounding box is empty or outside the image.
    BadBox {
        /// Instance id.
        id: u16,
    },
    /// Instance id 0 is reserved for "no instance".
    ReservedId,
    /// Two instances share one id.
    DuplicateId {
        /// The repeated id.
        id: u16,
    },
}

/// Why a parameter set was rejected by [`crate::Mapper::new`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamError {
    /// A parameter is out of its valid range; the name is the field name in [`crate::Params`].
    OutOfRange(&'static str),
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FrameError::EmptyFrame => write!(f, "frame has zero width or height"),
            FrameError::TooLarge { pixels, max_pixels } => {
                write!(f, "frame has {pixels} pixels, the capacity profile allows {max_pixels}")
            }
            FrameError::DepthLength { expected, found } => {
                write!(f, "depth buffer holds {found} samples, width x height needs {expected}")
            }
            FrameError::ColourLength { expected, found } => {
                write!(f, "colour buffer holds {found} bytes, width x height x 3 needs {expected}")
            }
            FrameError::BadIntrinsics => write!(f, "camera intrinsics are zero, negative or not finite"),
            FrameError::BadDepthScale => write!(f, "depth scale is zero, negative or not finite"),
            FrameError::BadPose => write!(f, "camera pose is not finite or not a proper rotation"),
            FrameError::NoValidDepth => write!(f, "no depth sample lies in the configured depth range"),
            FrameError::ConstantDepth { raw } => {
                write!(f, "every valid depth sample has the raw value {raw} (stuck sensor?)")
            }
            FrameError::Masks(e) => write!(f, "instance masks: {e}"),
        }
    }
}

impl fmt::Display for MaskError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            MaskError::SizeMismatch { mask, frame } => {
                write!(f, "mask is {}x{} pixels but the frame is {}x{}", mask.0, mask.1, frame.0, frame.1)
            }
            MaskError::PixelLength { expected, found } => {
                write!(f, "mask pixel buffer has {found} elements, expected {expected}")
            }
            MaskError::BadScore { id } => write!(f, "instance {id} has a score outside [0, 1]"),
            MaskError::BadBox { id } => write!(f, "instance {id} has an empty or out-of-image bounding box"),
            MaskError::ReservedId => write!(f, "instance id 0 is reserved for 'no instance'"),
            MaskError::DuplicateId { id } => write!(f, "instance id {id} appears twice"),
        }
    }
}

impl fmt::Display for ParamError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParamError::OutOfRange(name) => write!(f, "parameter `{name}` is out of range"),
        }
    }
}

impl From<MaskError> for FrameError {
    fn from(e: MaskError) -> Self {
        FrameError::Masks(e)
    }
}
