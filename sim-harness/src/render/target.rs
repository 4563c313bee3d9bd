//! A camera's targets: its uniform, the multisampled colour (four samples only) and the depth
//! it is drawn into, the resolved image, the linear-light image, the YUYV buffer and its
//! read-back, and the bind groups of the passes that read and write them.

use super::pipelines::{Layouts, READ_TWICE};
use super::{COLOUR_FORMAT, CameraEffects, DEPTH_FORMAT, LINEAR_FORMAT};
use wgpu::BufferUsages as Usages;

/// Per camera: its uniform, multisampled and resolved targets, and the YUYV buffers.
pub(super) struct CameraTarget {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) uniform: wgpu::Buffer,
    pub(super) camera_group: wgpu::BindGroup,
    /// Absent with one sample a pixel: the scene is drawn straight into `resolved`.
    pub(super) multisampled: Option<wgpu::TextureView>,
    pub(super) depth: wgpu::TextureView,
    pub(super) resolved: wgpu::TextureView,
    pub(super) packed: wgpu::Buffer,
    pub(super) readback: wgpu::Buffer,
    pub(super) pack_group: wgpu::BindGroup,
    /// The resolved image in linear light, and the pass that makes it (effects only).
    pub(super) linear_group: wgpu::BindGroup,
    pub(super) effects: wgpu::Buffer,
    pub(super) effects_group: wgpu::BindGroup,
}

pub(super) fn camera_target(
    device: &wgpu::Device,
    layouts: &Layouts,
    width: u32,
    height: u32,
    samples: u32,
) -> CameraTarget {
    let size = wgpu::Extent3d {
        width,
        height,
        depth_or_array_layers: 1,
    };
    let texture =
        |label, format, samples, usage| target_texture(device, size, label, format, samples, usage);
    let group = |label, layout, resources: &[wgpu::BindingResource<'_>]| {
        bind_group(device, label, layout, resources)
    };
    let multisampled = (samples > 1).then(|| {
        texture(
            "multisampled",
            COLOUR_FORMAT,
            samples,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        )
    });
    let depth = texture(
        "depth",
        DEPTH_FORMAT,
        samples,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let resolved = texture(
        "resolved",
        COLOUR_FORMAT,
        1,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let linear = texture(
        "linear light",
        LINEAR_FORMAT,
        1,
        wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let linear_group = group(
        "linear light",
        &layouts.linear,
        &[
            wgpu::BindingResource::TextureView(&resolved),
            wgpu::BindingResource::TextureView(&linear),
        ],
    );
    let bytes = u64::from(width) * u64::from(height) * 2;
    let packed = buffer(device, "yuyv", bytes, Usages::STORAGE | Usages::COPY_SRC);
    let readback = buffer(
        device,
        "yuyv readback",
        bytes,
        Usages::MAP_READ | Usages::COPY_DST,
    );
    let uniform = buffer(device, "camera", 64, Usages::UNIFORM | Usages::COPY_DST);
    let camera_group = group("camera", &layouts.camera, &[uniform.as_entire_binding()]);
    let pack_group = group(
        "pack",
        &layouts.pack,
        &[
            wgpu::BindingResource::TextureView(&resolved),
            packed.as_entire_binding(),
        ],
    );
    let effects = buffer(
        device,
        "camera effects",
        size_of::<CameraEffects>() as u64,
        READ_TWICE,
    );
    let effects_group = group(
        "camera effects",
        &layouts.effects,
        &[
            wgpu::BindingResource::TextureView(&linear),
            packed.as_entire_binding(),
            effects.as_entire_binding(),
            effects.as_entire_binding(),
        ],
    );
    CameraTarget {
        width,
        height,
        effects,
        effects_group,
        uniform,
        camera_group,
        multisampled,
        depth,
        resolved,
        packed,
        readback,
        pack_group,
        linear_group,
    }
}

/// A buffer of `size` bytes for `usage`, not mapped.
pub(super) fn buffer(
    device: &wgpu::Device,
    label: &str,
    size: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage,
        mapped_at_creation: false,
    })
}

/// A bind group of `layout` whose binding `i` is `resources[i]`.
pub(super) fn bind_group(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    resources: &[wgpu::BindingResource<'_>],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry<'_>> = (0u32..)
        .zip(resources)
        .map(|(binding, resource)| wgpu::BindGroupEntry {
            binding,
            resource: resource.clone(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

/// A view of a new 2D texture of `size`.
fn target_texture(
    device: &wgpu::Device,
    size: wgpu::Extent3d,
    label: &str,
    format: wgpu::TextureFormat,
    samples: u32,
    usage: wgpu::TextureUsages,
) -> wgpu::TextureView {
    device
        .create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: samples,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
        .create_view(&Default::default())
}
