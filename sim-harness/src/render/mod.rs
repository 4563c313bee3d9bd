//! Headless rendering of the Nao's two cameras with wgpu: the scene is drawn with 4x
//! multisampling (so that lines far away thin out instead of vanishing), resolved, packed
//! into YUYV by a compute shader and read back straight into a camera frame.
//!
//! On machines without a GPU it runs on lavapipe, Mesa's Vulkan driver on the CPU
//! (Debian's `mesa-vulkan-drivers`); its output is the same from run to run.

mod scene;

use std::sync::mpsc;

use dribble_controller::{CameraFrame, CameraPosition};
use glam::{Mat4, Quat, Vec3};
use wgpu::util::DeviceExt;

use crate::camera_geometry::CameraGeometry;
use crate::camera_model::CameraModel;
use crate::field::FieldGeometry;

pub use scene::{Mesh, Vertex, ball_mesh, static_scene};

const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const SAMPLES: u32 = 4;
/// Uniform buffer offsets must be multiples of this (wgpu's guaranteed minimum).
const UNIFORM_STRIDE: u64 = 256;
/// Above the walls: a pale, slightly blue hall.
const SKY: wgpu::Color = wgpu::Color {
    r: 0.78,
    g: 0.8,
    b: 0.84,
    a: 1.0,
};

/// Why rendering could not start or a frame could not be made.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no graphics adapter found ({0}). On a machine without a GPU install Mesa's CPU Vulkan \
         driver: apt-get install mesa-vulkan-drivers libvulkan1 (scripts/setup does this)"
    )]
    NoAdapter(String),
    #[error("the graphics device could not be opened: {0}")]
    Device(String),
    #[error("the adapter {adapter} cannot multisample {format:?} {SAMPLES} times")]
    NoMultisampling {
        adapter: String,
        format: wgpu::TextureFormat,
    },
    #[error("reading the {0} camera image back failed: {1}")]
    Readback(CameraPosition, String),
    #[error(
        "a {found_width}x{found_height} frame cannot hold the {camera} camera's {width}x{height} image"
    )]
    FrameSize {
        camera: CameraPosition,
        width: u32,
        height: u32,
        found_width: u32,
        found_height: u32,
    },
}

/// What moves in the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneState {
    /// The ball's centre and orientation, or `None` to leave it out.
    pub ball: Option<(Vec3, Quat)>,
}

struct GpuMesh {
    buffer: wgpu::Buffer,
    vertices: u32,
}

/// Per camera: its uniform, multisampled and resolved targets, and the YUYV buffers.
struct CameraTarget {
    width: u32,
    height: u32,
    uniform: wgpu::Buffer,
    camera_group: wgpu::BindGroup,
    multisampled: wgpu::TextureView,
    depth: wgpu::TextureView,
    resolved: wgpu::TextureView,
    packed: wgpu::Buffer,
    readback: wgpu::Buffer,
    pack_group: wgpu::BindGroup,
}

/// Renders both cameras; built once, used for every frame.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    scene_pipeline: wgpu::RenderPipeline,
    pack_pipeline: wgpu::ComputePipeline,
    static_mesh: GpuMesh,
    ball_mesh: GpuMesh,
    models: wgpu::Buffer,
    model_group: wgpu::BindGroup,
    targets: [CameraTarget; 2],
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("adapter", &self.adapter)
            .finish_non_exhaustive()
    }
}

impl Renderer {
    /// Opens the first adapter wgpu offers and builds the scene of `field`.
    pub fn new(
        field: &FieldGeometry,
        goal_depth: f32,
        cameras: &CameraGeometry,
    ) -> Result<Self, RenderError> {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle();
        descriptor.backends = wgpu::Backends::VULKAN;
        let instance = wgpu::Instance::new(descriptor);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|error| RenderError::NoAdapter(error.to_string()))?;
        let info = adapter.get_info();
        let adapter_name = format!(
            "{} ({:?}, {} {})",
            info.name, info.backend, info.driver, info.driver_info
        );
        let features = adapter.get_texture_format_features(COLOUR_FORMAT);
        if !features.flags.sample_count_supported(SAMPLES) {
            return Err(RenderError::NoMultisampling {
                adapter: adapter_name,
                format: COLOUR_FORMAT,
            });
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("dribble"),
            ..Default::default()
        }))
        .map_err(|error| RenderError::Device(error.to_string()))?;

        let camera_layout = uniform_layout(&device, "camera", false);
        let model_layout = uniform_layout(&device, "model", true);
        let scene_pipeline = scene_pipeline(&device, &camera_layout, &model_layout);
        let pack_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("pack"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: false },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pack_pipeline = pack_pipeline(&device, &pack_layout);

        let static_mesh = upload(&device, "static scene", &static_scene(field, goal_depth));
        let ball_mesh = upload(&device, "ball", &ball_mesh(field.ball_diameter / 2.0));
        let models = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("models"),
            size: 2 * UNIFORM_STRIDE,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        queue.write_buffer(
            &models,
            0,
            bytemuck::bytes_of(&Mat4::IDENTITY.to_cols_array()),
        );
        let model_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("models"),
            layout: &model_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &models,
                    offset: 0,
                    size: wgpu::BufferSize::new(64),
                }),
            }],
        });
        let targets = [CameraPosition::Top, CameraPosition::Bottom].map(|camera| {
            let mount = cameras.mount(camera);
            camera_target(
                &device,
                &camera_layout,
                &pack_layout,
                mount.width,
                mount.height,
            )
        });
        Ok(Self {
            device,
            queue,
            adapter: adapter_name,
            scene_pipeline,
            pack_pipeline,
            static_mesh,
            ball_mesh,
            models,
            model_group,
            targets,
        })
    }

    /// The adapter in use, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, llvmpipe ...)".
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// Renders what `camera` sees of `scene` into `frame`'s pixels (YUYV). The caller stamps
    /// the frame's sequence and time.
    pub fn render<const W: usize, const H: usize>(
        &mut self,
        position: CameraPosition,
        camera: &CameraModel,
        scene: &SceneState,
        frame: &mut CameraFrame<W, H>,
    ) -> Result<(), RenderError> {
        let target = &self.targets[position.index()];
        if (target.width, target.height) != (W as u32, H as u32) {
            return Err(RenderError::FrameSize {
                camera: position,
                width: target.width,
                height: target.height,
                found_width: W as u32,
                found_height: H as u32,
            });
        }
        self.queue.write_buffer(
            &target.uniform,
            0,
            bytemuck::bytes_of(&camera.view_projection().to_cols_array()),
        );
        if let Some((centre, rotation)) = scene.ball {
            let model = Mat4::from_rotation_translation(rotation, centre);
            self.queue.write_buffer(
                &self.models,
                UNIFORM_STRIDE,
                bytemuck::bytes_of(&model.to_cols_array()),
            );
        }
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("scene"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &target.multisampled,
                    depth_slice: None,
                    resolve_target: Some(&target.resolved),
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(SKY),
                        store: wgpu::StoreOp::Discard,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &target.depth,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            pass.set_pipeline(&self.scene_pipeline);
            pass.set_bind_group(0, &target.camera_group, &[]);
            pass.set_bind_group(1, &self.model_group, &[0]);
            pass.set_vertex_buffer(0, self.static_mesh.buffer.slice(..));
            pass.draw(0..self.static_mesh.vertices, 0..1);
            if scene.ball.is_some() {
                pass.set_bind_group(1, &self.model_group, &[UNIFORM_STRIDE as u32]);
                pass.set_vertex_buffer(0, self.ball_mesh.buffer.slice(..));
                pass.draw(0..self.ball_mesh.vertices, 0..1);
            }
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("pack yuyv"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pack_pipeline);
            pass.set_bind_group(0, &target.pack_group, &[]);
            pass.dispatch_workgroups((target.width / 2).div_ceil(8), target.height.div_ceil(8), 1);
        }
        encoder.copy_buffer_to_buffer(&target.packed, 0, &target.readback, 0, target.packed.size());
        self.queue.submit([encoder.finish()]);

        let slice = target.readback.slice(..);
        let (sender, receiver) = mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|error| RenderError::Readback(position, error.to_string()))?;
        receiver
            .recv()
            .map_err(|error| RenderError::Readback(position, error.to_string()))?
            .map_err(|error| RenderError::Readback(position, error.to_string()))?;
        {
            let mapped = slice
                .get_mapped_range()
                .map_err(|error| RenderError::Readback(position, error.to_string()))?;
            frame.as_bytes_mut().copy_from_slice(&mapped);
        }
        target.readback.unmap();
        Ok(())
    }
}

fn uniform_layout(device: &wgpu::Device, label: &str, dynamic: bool) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &[wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: dynamic,
                min_binding_size: wgpu::BufferSize::new(64),
            },
            count: None,
        }],
    })
}

fn scene_pipeline(
    device: &wgpu::Device,
    camera_layout: &wgpu::BindGroupLayout,
    model_layout: &wgpu::BindGroupLayout,
) -> wgpu::RenderPipeline {
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("scene"),
        source: wgpu::ShaderSource::Wgsl(include_str!("scene.wgsl").into()),
    });
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("scene"),
        bind_group_layouts: &[Some(camera_layout), Some(model_layout)],
        ..Default::default()
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("scene"),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &shader,
            entry_point: Some("vertex_main"),
            compilation_options: Default::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: size_of::<Vertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x3],
            })],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::LessEqual),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: wgpu::MultisampleState {
            count: SAMPLES,
            ..Default::default()
        },
        fragment: Some(wgpu::FragmentState {
            module: &shader,
            entry_point: Some("fragment_main"),
            compilation_options: Default::default(),
            targets: &[Some(COLOUR_FORMAT.into())],
        }),
        multiview_mask: None,
        cache: None,
    })
}

fn pack_pipeline(device: &wgpu::Device, layout: &wgpu::BindGroupLayout) -> wgpu::ComputePipeline {
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("yuyv"),
        source: wgpu::ShaderSource::Wgsl(include_str!("yuyv.wgsl").into()),
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("yuyv"),
        bind_group_layouts: &[Some(layout)],
        ..Default::default()
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("yuyv"),
        layout: Some(&pipeline_layout),
        module: &shader,
        entry_point: Some("pack_main"),
        compilation_options: Default::default(),
        cache: None,
    })
}

fn upload(device: &wgpu::Device, label: &str, mesh: &Mesh) -> GpuMesh {
    GpuMesh {
        buffer: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::cast_slice(&mesh.vertices),
            usage: wgpu::BufferUsages::VERTEX,
        }),
        vertices: mesh.vertices.len() as u32,
    }
}

fn camera_target(
    device: &wgpu::Device,
    camera_layout: &wgpu::BindGroupLayout,
    pack_layout: &wgpu::BindGroupLayout,
    width: u32,
    height: u32,
) -> CameraTarget {
    let size = wgpu::Extent3d {
        width,
        height,
        depth_or_array_layers: 1,
    };
    let texture = |label: &str, format, samples, usage| {
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
    };
    let multisampled = texture(
        "multisampled",
        COLOUR_FORMAT,
        SAMPLES,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let depth = texture(
        "depth",
        DEPTH_FORMAT,
        SAMPLES,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let resolved = texture(
        "resolved",
        COLOUR_FORMAT,
        1,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let bytes = u64::from(width) * u64::from(height) * 2;
    let packed = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("yuyv"),
        size: bytes,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let readback = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("yuyv readback"),
        size: bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let uniform = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("camera"),
        size: 64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let camera_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("camera"),
        layout: camera_layout,
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: uniform.as_entire_binding(),
        }],
    });
    let pack_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("pack"),
        layout: pack_layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(&resolved),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: packed.as_entire_binding(),
            },
        ],
    });
    CameraTarget {
        width,
        height,
        uniform,
        camera_group,
        multisampled,
        depth,
        resolved,
        packed,
        readback,
        pack_group,
    }
}
