//! GPU-free core of brickray.
//!
//! * [`volume`]: scalar volumes in memory ([`Volume`]), their sample types and
//!   value ranges;
//! * [`tf`]: 1D RGBA transfer functions and the opacity prefix-sum table that
//!   answers "is the value range `[min, max]` transparent?" in O(1);
//! * [`anatomy`]: anatomical orientation (RAS+ axis codes, the upright
//!   display frame, views from A/P/L/R/S/I, radiological slices);
//! * [`channels`]: multi-channel volumes, per-channel styles and how the
//!   channels of a sample mix;
//! * [`brick`]: the brick-octree vocabulary (node keys, layout, [`BrickSource`]);
//! * [`camera`]: perspective and orthographic cameras and the ray model shared by
//!   the GPU ray caster and the CPU reference;
//! * [`settings`]: render modes and switches;
//! * [`macrocell`]: the min/max macro-cell grid used for empty-space skipping,
//!   and its brick analogue (sub-cell ranges);
//! * [`texel`]: how samples are stored in GPU textures ([`SampleEncoding`]);
//! * [`lod`]: per-node error bounds of level of detail and their cost under a
//!   transfer function (error-aware refinement);
//! * [`moments`]: the mean and spread of the finest voxels each coarse voxel
//!   stands for, composed exactly across levels (consistent classification of
//!   coarse levels with [`tf::spread`]);
//! * [`synthetic`]: procedural test volumes (sphere, Marschner-Lobb);
//! * [`slice`](mod@slice): slice views (a plane or a thick slab through the volume);
//! * [`window`]: window and level, CT presets and colour maps of MIP and slices.
//! * [`labels`]: label maps (segmentations): the mode pyramid, label tables
//!   (colour, opacity, visibility, selection, hover) and their exact TF;
//! * [`range`]: byte-range reads ([`RangeReader`]), the seam between a
//!   format's parser and where its bytes live.

pub mod anatomy;
pub mod brick;
pub mod camera;
pub mod channels;
pub mod labels;
pub mod lod;
pub mod macrocell;
pub mod moments;
mod node_error;
pub mod overlay;
mod pyramid;
pub mod range;
pub mod settings;
pub mod skip_rule;
pub mod slice;
pub mod synthetic;
pub mod texel;
pub mod tf;
pub mod volume;
pub mod window;

pub use brick::{
    BrickError, BrickSource, CutLeaf, EmptyReason, LeafKind, NodeInfo, NodeKey, NodeKind, NodeMap,
    NodeSet, OctreeLayout, level_volume,
};
pub use camera::{
    Camera, CameraError, DepthConvention, DepthMap, FrameError, FrameView, Projection, Ray, RayGen,
    ViewGenerations, VolumeFrame,
};
pub use channels::{ChannelError, ChannelSource, ChannelStyle, ChannelVolume, MAX_CHANNELS};
pub use labels::{LABEL_TABLE_ENTRIES, LabelError, LabelStyle, LabelTable};
pub use lod::{
    BinStats, ERROR_BINS, LodMetric, NodeError, TfErrorTable, node_pixel_error, node_tf_error,
    node_tf_error_expected, node_visible_error,
};
pub use macrocell::{
    MacroCellGrid, empty_distance, mip_skip_counts, sub_cell_ranges, sub_cell_spreads,
    sub_cells_per_axis,
};
pub use moments::{MomentGrid, Moments, SpreadError, SpreadSource};
pub use overlay::{LabelOverlay, OverlayError, OverlayMode, OverlayStyle, overlay_transform};
pub use pyramid::{ALL_AXES, Children, LayoutError, MAX_LEVELS, anisotropic_split_masks};
pub use range::{CancelToken, MemRangeReader, ObjectReader, ObjectSpan, RangeRead, RangeReader};
pub use settings::{
    ADAPTIVE_STEP_DOUBLINGS, Accel, ClipBox, RenderMode, RenderSettings, SettingsError, Shading,
    adaptive_step_doublings,
};
pub use skip_rule::{
    DVR_SHADED_SKIP_SHARE_MIN, DVR_SHADED_SKIP_SHARE_MIN_BRICKS, DVR_SKIP_SHARE_MIN,
    DVR_SKIP_SHARE_MIN_BRICKS, MIP_SKIP_SHARE_MIN, MIP_SKIP_SHARE_MIN_BRICKS, ShareByStep,
    dvr_skip_share_min, dvr_skip_share_min_bricks, mip_skipping_pays,
};
pub use slice::{Slab, SlabMode, SliceAxis, SliceError, SliceGeometry, SliceView};
pub use texel::{SampleEncoding, TexelCaps, TexelFormat, U8Filtering};
pub use tf::{TfError, TransferFunction};
pub use volume::{DType, Volume, VolumeData, VolumeDesc, VolumeError, VolumeKind};
pub use window::{ColorMap, CtPreset, Intensity, Window, WindowError, histogram};
