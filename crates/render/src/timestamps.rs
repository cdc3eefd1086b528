//! GPU timestamps of the ray-cast pass, written into a query set the host
//! owns ([`VolumeRenderer::set_pass_timestamps`](crate::VolumeRenderer::set_pass_timestamps)).
//! The renderer only names the query set in the pass's `timestamp_writes`: the
//! host resolves and reads it (the library never submits and never waits).

use crate::RenderError;

/// Where the ray-cast compute pass writes its timestamps: the query
/// indices of its beginning and its end in a host-owned query set of type
/// [`wgpu::QueryType::Timestamp`], created on the renderer's device.
///
/// The two timestamps bracket the ray-cast pass only: not the isosurface
/// prediction's reprojection pass recorded before it
/// ([`VolumeRenderer::set_prediction`](crate::VolumeRenderer::set_prediction)),
/// not the depth-only occlusion-query pass, the clears and the copies
/// recorded after it out of core, and not the composite draw of
/// [`VolumeRenderer::render`](crate::VolumeRenderer::render).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PassTimestamps {
    /// The query set (wgpu resources are reference-counted handles: the
    /// renderer keeps a clone).
    pub query_set: wgpu::QuerySet,
    /// The index written at the beginning of the pass.
    pub beginning: u32,
    /// The index written at the end of the pass.
    pub end: u32,
}

impl PassTimestamps {
    /// Checks that `device` can write these timestamps: it has
    /// [`wgpu::Features::TIMESTAMP_QUERY`] ([`RenderError::MissingFeature`]),
    /// and the query set is of type timestamp with both indices inside it and
    /// distinct ([`RenderError::BadTimestampQuery`]).
    pub(crate) fn check(&self, device: &wgpu::Device) -> Result<(), RenderError> {
        let feature = wgpu::Features::TIMESTAMP_QUERY;
        if !device.features().contains(feature) {
            return Err(RenderError::MissingFeature {
                feature,
                what: "timestamps of the ray-cast pass",
            });
        }
        let ty = self.query_set.ty();
        let count = self.query_set.count();
        let timestamp = matches!(ty, wgpu::QueryType::Timestamp);
        if !timestamp || self.beginning >= count || self.end >= count || self.beginning == self.end
        {
            return Err(RenderError::BadTimestampQuery {
                ty,
                count,
                beginning: self.beginning,
                end: self.end,
            });
        }
        Ok(())
    }

    /// The compute pass's `timestamp_writes`.
    pub(crate) fn writes(&self) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.query_set,
            beginning_of_pass_write_index: Some(self.beginning),
            end_of_pass_write_index: Some(self.end),
        }
    }
}
