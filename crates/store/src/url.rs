//! Opening stores and OME-Zarr images from URLs (feature `remote`): a store
//! over a remote range reader, an image over remote objects, each through
//! the disk cache when one is configured, and telling the two apart.

use crate::error::StoreError;
use crate::reader::{Store, open};
use brickray_core::BrickSource;
use std::path::Path;
use std::sync::Arc;

/// Opens a store over S3, GCS, Azure or HTTP(S) (`s3://bucket/key`,
/// `gs://…`, `az://…`, `https://…`) through a
/// [`RemoteRangeReader`](brickray_remote::RemoteRangeReader) configured by
/// `opts`. Three requests: the object's size, the header, the metadata
/// after the payload. With [`RemoteOptions::disk_cache`](brickray_remote::RemoteOptions::disk_cache)
/// the ranges it fetches are kept on the local disk
/// ([`DiskCached`](brickray_remote::DiskCached)). Errors name the URL; a
/// remote failure is a
/// [`StoreError::Io`] whose source holds the typed
/// [`RemoteError`](brickray_remote::RemoteError) (see
/// [`RemoteError::from_io`](brickray_remote::RemoteError::from_io)).
pub fn open_url(url: &str, opts: &brickray_remote::RemoteOptions) -> Result<Store, StoreError> {
    let reader = brickray_remote::RemoteRangeReader::open(url, opts)
        .map_err(|e| StoreError::io(Path::new(url), e.into()))?;
    match &opts.disk_cache {
        Some(config) => {
            // What changes when the object does: a new ETag or length is
            // another folder of the cache.
            let identity = format!(
                "{url}\n{}\n{}",
                reader.etag().unwrap_or(""),
                reader.object_len()
            );
            let cached = brickray_remote::DiskCached::new(reader, &identity, config)
                .map_err(|e| StoreError::io(&config.dir, e))?;
            Store::open_with(cached, url)
        }
        None => Store::open_with(reader, url),
    }
}

/// Opens a store from a URL ([`open_url`], configured by
/// [`RemoteOptions::from_env`](brickray_remote::RemoteOptions::from_env))
/// or a local path ([`open`]).
pub fn open_any(path_or_url: &str) -> Result<Store, StoreError> {
    if brickray_remote::is_url(path_or_url) {
        open_url(path_or_url, &brickray_remote::RemoteOptions::from_env())
    } else {
        open(path_or_url)
    }
}

/// Opens an OME-Zarr image (0.4 or 0.5) over S3, GCS, Azure or HTTP(S)
/// (`s3://bucket/path/image.zarr`, `https://host/path/image.zarr`) as a
/// streamed brick source ([`ZarrBrickSource`](brickray_io::zarr::ZarrBrickSource)
/// over [`RemoteObjects`](brickray_remote::RemoteObjects)): the channel and
/// time point of `read`, bricks of `brick` voxels with `apron` voxels of
/// apron. Set-up reads the metadata and the coarsest level (for the value
/// range); bricks read the chunks they need, each shard's index once. A
/// missing chunk (404, or S3's 403) reads as the fill value; a remote
/// failure is a [`StoreError::Input`] whose I/O source holds the typed
/// [`RemoteError`](brickray_remote::RemoteError). With
/// [`RemoteOptions::disk_cache`](brickray_remote::RemoteOptions::disk_cache)
/// the chunks, shard indices and absent keys it fetches are kept on the
/// local disk ([`DiskCachedObjects`](brickray_remote::DiskCachedObjects);
/// metadata is always fetched).
pub fn open_zarr_url(
    url: &str,
    opts: &brickray_remote::RemoteOptions,
    read: &brickray_io::ReadOptions,
    brick: u32,
    apron: u32,
) -> Result<brickray_io::zarr::ZarrBrickSource, StoreError> {
    Ok(brickray_io::zarr::ZarrBrickSource::open_objects(
        zarr_objects(url, opts)?,
        read,
        brick,
        apron,
        None,
    )?)
}

/// The objects of the OME-Zarr image at `url`, through the disk cache of
/// [`RemoteOptions::disk_cache`](brickray_remote::RemoteOptions::disk_cache)
/// when there is one ([`DiskCachedObjects`](brickray_remote::DiskCachedObjects)).
fn zarr_objects(
    url: &str,
    opts: &brickray_remote::RemoteOptions,
) -> Result<Arc<dyn brickray_core::ObjectReader>, StoreError> {
    let objects = brickray_remote::RemoteObjects::open(url, opts)
        .map_err(|e| StoreError::io(Path::new(url), e.into()))?;
    Ok(match &opts.disk_cache {
        Some(config) => Arc::new(
            brickray_remote::DiskCachedObjects::for_image(objects, config)
                .map_err(|e| StoreError::io(Path::new(url), e))?,
        ),
        None => Arc::new(objects),
    })
}

/// Reads an OME-Zarr image at `url` slab by slab (level, channel and time
/// point of `read`): the input of a store build from a URL
/// (`brickray-store build URL out.brs`).
pub fn open_zarr_reader_url(
    url: &str,
    opts: &brickray_remote::RemoteOptions,
    read: &brickray_io::ReadOptions,
) -> Result<brickray_io::zarr::ZarrReader, StoreError> {
    Ok(brickray_io::zarr::ZarrReader::open_objects(
        zarr_objects(url, opts)?,
        read,
    )?)
}

/// The OME-Zarr image at `url`, its metadata read (channels, levels and
/// their dims, `omero`), no chunk fetched: what decides how to open it.
pub fn open_zarr_image_url(
    url: &str,
    opts: &brickray_remote::RemoteOptions,
) -> Result<brickray_io::zarr::OmeZarr, StoreError> {
    Ok(brickray_io::zarr::OmeZarr::open_objects(zarr_objects(
        url, opts,
    )?)?)
}

/// Every channel of the OME-Zarr image at `url` read whole
/// ([`brickray_io::read_channels`] of a remote image: the level, time point
/// and channels of `read`, each channel's `omero` metadata), through the
/// disk cache of `opts` when there is one. For images that fit in memory
/// (the multi-channel renderer draws them in core); a larger one is read at
/// a coarser level (`ReadOptions::level`).
pub fn read_zarr_channels_url(
    url: &str,
    opts: &brickray_remote::RemoteOptions,
    read: &brickray_io::ReadOptions,
) -> Result<brickray_io::ReadChannels, StoreError> {
    let path = Path::new(url);
    let readers =
        brickray_io::zarr::ZarrReader::open_channels_objects(zarr_objects(url, opts)?, read)?;
    Ok(brickray_io::ReadChannels::read(path, readers)?)
}

/// The channels of the OME-Zarr image at `url` streamed together as one
/// [`brickray_core::ChannelSource`] (every channel, at most four, or those
/// `read.channels` selects; each read once per brick), with what its
/// `omero` metadata says of each: a multi-channel image too large for
/// memory, drawn out of core.
pub fn open_zarr_channels_url(
    url: &str,
    opts: &brickray_remote::RemoteOptions,
    read: &brickray_io::ReadOptions,
    brick: u32,
    apron: u32,
) -> Result<(brickray_core::ChannelSource, Vec<brickray_io::ChannelInfo>), StoreError> {
    Ok(brickray_io::zarr::ZarrBrickSource::open_channels_objects(
        zarr_objects(url, opts)?,
        read,
        brick,
        apron,
    )?)
}

/// Whether the remote `url` names an OME-Zarr image rather than a store:
/// its path ends in `.zarr` (or `.zarr/`), or, for a name ending in neither
/// `.zarr` nor `.brs`, the folder it names holds a `zarr.json` or `.zattrs`
/// with `multiscales` (one or two small requests).
pub fn is_zarr_url(url: &str, opts: &brickray_remote::RemoteOptions) -> bool {
    let name = url.trim_end_matches('/').to_ascii_lowercase();
    if name.ends_with(".zarr") {
        return true;
    }
    if name.ends_with(&format!(".{}", crate::EXTENSION)) {
        return false;
    }
    let Ok(objects) = brickray_remote::RemoteObjects::open(url, opts) else {
        return false;
    };
    ["zarr.json", ".zattrs"].iter().any(|key| {
        objects
            .get(key, brickray_core::ObjectSpan::Suffix(1 << 20))
            .ok()
            .flatten()
            .and_then(|(b, _)| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .is_some_and(|v| {
                let attrs = v.get("attributes").and_then(|a| a.get("ome")).unwrap_or(&v);
                attrs.get("multiscales").is_some()
            })
    })
}

/// Opens a brick source from a URL or a local path: an OME-Zarr image over
/// the network ([`is_zarr_url`], [`open_zarr_url`] with the default store's
/// brick and apron, the first channel and time point), a store over the
/// network ([`open_url`]), or a local store ([`open`]). Remote access is
/// configured by [`RemoteOptions::from_env`](brickray_remote::RemoteOptions::from_env).
pub fn open_source_any(path_or_url: &str) -> Result<Arc<dyn BrickSource>, StoreError> {
    if brickray_remote::is_url(path_or_url) {
        let o = brickray_remote::RemoteOptions::from_env();
        if is_zarr_url(path_or_url, &o) {
            let d = crate::BuildOptions::default();
            return Ok(Arc::new(open_zarr_url(
                path_or_url,
                &o,
                &brickray_io::ReadOptions::default(),
                d.brick,
                d.apron,
            )?));
        }
        return Ok(Arc::new(open_url(path_or_url, &o)?));
    }
    Ok(Arc::new(open(path_or_url)?))
}
