//! Headless rendering of the Nao's two cameras with wgpu: the scene is drawn with 4x
//! multisampling (so that lines far away thin out instead of vanishing; one sample is a
//! setting beside it, [`Multisampling`]), resolved, packed into YUYV by a compute shader and
//! read back straight into a camera frame.
//!
//! An episode's conditions ([`crate::conditions`]) change three things, each only when one
//! applies, so the clean render stays the paper's bit for bit: the venue's mesh, a lit
//! pipeline (`scene_lit.wgsl`: a directional light's shadows and bright spots) in place of
//! the flat one, and an effects pass (`camera_effects.wgsl`: exposure, noise, white balance,
//! blur and skew, lens, contrast) in place of the plain YUYV packing.
//!
//! On machines without a GPU it runs on lavapipe, Mesa's Vulkan driver on the CPU
//! (Debian's `mesa-vulkan-drivers`); its output is the same from run to run.

mod clean_twin;
mod multisampling;
mod pipelines;
mod scene;
mod shadow_casters;
mod target;

use std::sync::mpsc;

use dribble_controller::{CameraFrame, CameraPosition};
use glam::{Mat4, Quat, Vec3};
use wgpu::util::DeviceExt;

use crate::camera_geometry::CameraGeometry;
use crate::camera_model::CameraModel;
use crate::conditions::camera::CameraEffects;
use crate::conditions::{EpisodeLook, Occluder};
use crate::field::FieldGeometry;
use pipelines::{EffectsStages, Pipelines, READ_TWICE};
use target::{CameraTarget, camera_target};
use wgpu::BufferUsages as Usages;

pub use clean_twin::CleanTwin;
pub use multisampling::{Multisampling, MultisamplingError};
pub use scene::{Mesh, StaticScene, Vertex, ball_mesh, static_scene, static_scene_in};

const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// The resolved image in linear light, for the effects pass.
const LINEAR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// Uniform buffer offsets must be multiples of this (wgpu's guaranteed minimum).
const UNIFORM_STRIDE: u64 = 256;
/// Shadow casters and bright spots the lit pipeline takes (`scene_lit.wgsl`).
const MAX_CASTERS: usize = 64;
const MAX_SPOTS: usize = 8;

/// The lit pipeline's uniform (`Light` in `scene_lit.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct LightUniform {
    towards_share: [f32; 4],
    counts: [u32; 4],
    casters: [[f32; 4]; 2 * MAX_CASTERS],
    spots: [[f32; 4]; 2 * MAX_SPOTS],
}

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
    #[error("the adapter {adapter} cannot multisample {format:?} {samples} times")]
    NoMultisampling {
        adapter: String,
        format: wgpu::TextureFormat,
        samples: u32,
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
    /// Simulated time of the frame, nanoseconds since the episode's start (what the
    /// conditions' exposure steps, drift and noise follow).
    pub time_ns: u64,
}

struct GpuMesh {
    buffer: wgpu::Buffer,
    vertices: u32,
}

/// The static scene on the device: what stands, then the ground's layers from `ground_start`.
struct GpuScene {
    mesh: GpuMesh,
    ground_start: u32,
}

impl GpuScene {
    fn upload(device: &wgpu::Device, scene: &StaticScene) -> Self {
        Self {
            mesh: upload(device, "static scene", &scene.mesh),
            ground_start: scene.ground_start as u32,
        }
    }
}

/// Renders both cameras; built once, used for every frame.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    multisampling: Multisampling,
    pipelines: Pipelines,
    field: FieldGeometry,
    goal_depth: f32,
    cameras: CameraGeometry,
    static_scene: GpuScene,
    ball_mesh: GpuMesh,
    models: wgpu::Buffer,
    model_group: wgpu::BindGroup,
    light: wgpu::Buffer,
    light_group: wgpu::BindGroup,
    /// The episode's light as the lit shader reads it, and every caster it may be given (the
    /// ball's first, placed at every frame); a frame is given those whose shadow can fall
    /// in its camera's view ([`shadow_casters`]).
    light_uniform: Box<LightUniform>,
    casters: Vec<Occluder>,
    targets: [CameraTarget; 2],
    /// The episode's look: clean until [`Renderer::begin_episode`] says otherwise.
    look: EpisodeLook,
    /// Each camera's rotation and time at its previous frame (its angular velocity).
    previous: [Option<(Quat, u64)>; 2],
    /// Every frame drawn a second time without camera effects and light, when asked for.
    clean_twin: Option<Box<CleanTwin>>,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("adapter", &self.adapter)
            .finish_non_exhaustive()
    }
}

impl Renderer {
    /// Opens the first adapter wgpu offers and builds the scene of `field`, drawn with four
    /// samples a pixel (every shipped result's frames).
    pub fn new(
        field: &FieldGeometry,
        goal_depth: f32,
        cameras: &CameraGeometry,
    ) -> Result<Self, RenderError> {
        Self::with_multisampling(field, goal_depth, cameras, Multisampling::Four)
    }

    /// As [`Renderer::new`], each pixel drawn with `multisampling`'s samples.
    pub fn with_multisampling(
        field: &FieldGeometry,
        goal_depth: f32,
        cameras: &CameraGeometry,
        multisampling: Multisampling,
    ) -> Result<Self, RenderError> {
        let samples = multisampling.samples();
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
        if !features.flags.sample_count_supported(samples) {
            return Err(RenderError::NoMultisampling {
                adapter: adapter_name,
                format: COLOUR_FORMAT,
                samples,
            });
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("dribble"),
            ..Default::default()
        }))
        .map_err(|error| RenderError::Device(error.to_string()))?;

        let (layouts, pipelines) = Pipelines::new(&device, samples);
        let light = target::buffer(
            &device,
            "light",
            size_of::<LightUniform>() as u64,
            READ_TWICE,
        );
        let light_group = target::bind_group(
            &device,
            "light",
            &layouts.light,
            &[light.as_entire_binding(), light.as_entire_binding()],
        );

        let static_scene = GpuScene::upload(&device, &static_scene(field, goal_depth));
        let ball_mesh = upload(&device, "ball", &ball_mesh(field.ball_diameter / 2.0));
        let models = target::buffer(
            &device,
            "models",
            2 * UNIFORM_STRIDE,
            Usages::UNIFORM | Usages::COPY_DST,
        );
        queue.write_buffer(
            &models,
            0,
            bytemuck::bytes_of(&Mat4::IDENTITY.to_cols_array()),
        );
        let model_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("models"),
            layout: &layouts.model,
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
            camera_target(&device, &layouts, mount.width, mount.height, samples)
        });
        Ok(Self {
            device,
            queue,
            adapter: adapter_name,
            multisampling,
            pipelines,
            field: *field,
            goal_depth,
            cameras: *cameras,
            static_scene,
            ball_mesh,
            models,
            model_group,
            light,
            light_group,
            light_uniform: Box::new(bytemuck::Zeroable::zeroed()),
            casters: Vec::new(),
            targets,
            look: EpisodeLook::clean(),
            previous: [None; 2],
            clean_twin: None,
        })
    }

    /// This renderer with a [`CleanTwin`] beside it: a second renderer (on the same kind of
    /// adapter) that draws every frame again without camera effects or light. The
    /// runner records the twin's thumbnails beside each row's; rendering costs up to twice.
    pub fn with_clean_twin(mut self) -> Result<Self, RenderError> {
        let twin = Renderer::with_multisampling(
            &self.field,
            self.goal_depth,
            &self.cameras,
            self.multisampling,
        )?;
        self.clean_twin = Some(Box::new(CleanTwin::new(twin)));
        Ok(self)
    }

    /// The clean twin, when this renderer has one.
    pub fn clean_twin_mut(&mut self) -> Option<&mut CleanTwin> {
        self.clean_twin.as_deref_mut()
    }

    /// Sets the look of the episode about to start: its venue's mesh (built anew only when it
    /// differs from the last one), its light, its camera effects. Until the first call, and
    /// after a call with a clean look, frames are the paper's clean render.
    pub fn begin_episode(&mut self, look: &EpisodeLook) {
        if look.layout != self.look.layout {
            let scene = static_scene_in(&self.field, self.goal_depth, &look.layout);
            self.static_scene = GpuScene::upload(&self.device, &scene);
        }
        if let Some(sun) = &look.layout.sunlight {
            let mut uniform = LightUniform {
                towards_share: [sun.towards.x, sun.towards.y, sun.towards.z, sun.share],
                counts: [0; 4],
                casters: [[0.0; 4]; 2 * MAX_CASTERS],
                spots: [[0.0; 4]; 2 * MAX_SPOTS],
            };
            // The ball first (placed at every frame), then goals, then what stands about.
            let radius = self.field.ball_diameter / 2.0;
            self.casters = std::iter::once(Occluder::new(Vec3::ZERO, Vec3::ZERO, radius))
                .chain(crate::conditions::venue::goal_occluders(&self.field))
                .chain(look.layout.occluders())
                .take(MAX_CASTERS)
                .collect();
            for (i, spot) in sun.spots.iter().take(MAX_SPOTS).enumerate() {
                let (sin, cos) = spot.angle.sin_cos();
                uniform.spots[2 * i] = [
                    spot.centre.x,
                    spot.centre.y,
                    spot.half_axes.x,
                    spot.half_axes.y,
                ];
                uniform.spots[2 * i + 1] = [cos, sin, spot.gain, 0.0];
            }
            uniform.counts = [0, sun.spots.len().min(MAX_SPOTS) as u32, 0, 0];
            *self.light_uniform = uniform;
        }
        self.look = look.clone();
        self.previous = [None; 2];
        if let Some(twin) = self.clean_twin.as_deref_mut() {
            twin.begin_episode(look);
        }
    }

    /// The samples each pixel is drawn with.
    pub fn multisampling(&self) -> Multisampling {
        self.multisampling
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
        let (lit, effects) = self.write_frame_state(position, camera, scene);
        let commands = self.encode_frame(position, lit, scene.ball.is_some(), effects.as_ref());
        self.queue.submit([commands]);
        self.read_back(position, frame)
    }

    /// Writes what this frame's passes read: the camera's matrix, the ball's, the ball's
    /// shadow caster (lit scenes) and the camera's effects (when the episode has any). Returns
    /// whether the scene is lit and the effects, when the effects pass runs.
    fn write_frame_state(
        &mut self,
        position: CameraPosition,
        camera: &CameraModel,
        scene: &SceneState,
    ) -> (bool, Option<CameraEffects>) {
        let target = &self.targets[position.index()];
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
        let lit = self.look.layout.sunlight.is_some();
        if lit {
            // The ball's shadow: its caster follows it (a radius of 0 while it is left out).
            if let Some(ball) = self.casters.first_mut() {
                let centre = scene.ball.map_or(Vec3::ZERO, |(centre, _)| centre);
                ball.a = centre;
                ball.b = centre;
                ball.radius = scene.ball.map_or(0.0, |_| self.field.ball_diameter / 2.0);
            }
            write_casters(
                &mut self.light_uniform,
                &self.casters,
                (&self.queue, &self.light),
                camera,
            );
        }
        let index = position.index();
        let effects = (!self.look.camera.is_none()).then(|| {
            let previous = self.previous[index].map(|(rotation, time_ns)| {
                let dt_s = scene.time_ns.saturating_sub(time_ns) as f32 * 1e-9;
                (rotation, dt_s)
            });
            self.look.camera.frame(
                index as u32,
                scene.time_ns,
                scene.time_ns as f32 * 1e-9,
                camera.rotation,
                previous,
                (target.width, target.height),
                (camera.fx, camera.fy),
            )
        });
        self.previous[index] = Some((camera.rotation, scene.time_ns));
        if let Some(effects) = &effects {
            self.queue
                .write_buffer(&target.effects, 0, bytemuck::bytes_of(effects));
        }
        (lit, effects)
    }

    /// The frame's commands: the scene drawn and resolved, then packed into YUYV (through the
    /// linear image and the effects when they run), and copied for read-back.
    fn encode_frame(
        &self,
        position: CameraPosition,
        lit: bool,
        ball: bool,
        effects: Option<&CameraEffects>,
    ) -> wgpu::CommandBuffer {
        let target = &self.targets[position.index()];
        let [r, g, b] = self.look.layout.sky;
        let sky = wgpu::Color { r, g, b, a: 1.0 };
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        // Four samples: drawn into the multisampled image, resolved by the driver; one: drawn
        // straight into the resolved image, which must then be stored.
        let (view, resolve_target, store) = match &target.multisampled {
            Some(multisampled) => (multisampled, Some(&target.resolved), wgpu::StoreOp::Discard),
            None => (&target.resolved, None, wgpu::StoreOp::Store),
        };
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("scene"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(sky),
                        store,
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
            let (standing, ground) = if lit {
                (&self.pipelines.lit, &self.pipelines.lit_ground)
            } else {
                (&self.pipelines.scene, &self.pipelines.ground)
            };
            pass.set_pipeline(standing);
            if lit {
                pass.set_bind_group(2, &self.light_group, &[]);
            }
            pass.set_bind_group(0, &target.camera_group, &[]);
            pass.set_bind_group(1, &self.model_group, &[0]);
            let scene = &self.static_scene;
            pass.set_vertex_buffer(0, scene.mesh.buffer.slice(..));
            pass.draw(0..scene.ground_start, 0..1);
            pass.set_pipeline(ground);
            pass.draw(scene.ground_start..scene.mesh.vertices, 0..1);
            if ball {
                pass.set_pipeline(standing);
                pass.set_bind_group(1, &self.model_group, &[UNIFORM_STRIDE as u32]);
                pass.set_vertex_buffer(0, self.ball_mesh.buffer.slice(..));
                pass.draw(0..self.ball_mesh.vertices, 0..1);
            }
        }
        if effects.is_some() {
            let mut pass = compute_pass(&mut encoder, "linear light");
            pass.set_pipeline(&self.pipelines.linear);
            pass.set_bind_group(0, &target.linear_group, &[]);
            pass.dispatch_workgroups(target.width.div_ceil(8), target.height.div_ceil(8), 1);
        }
        {
            let mut pass = compute_pass(&mut encoder, "pack yuyv");
            if let Some(effects) = effects {
                let stages = EffectsStages::of(effects);
                pass.set_pipeline(self.pipelines.effects(&self.device, stages));
                pass.set_bind_group(0, &target.effects_group, &[]);
            } else {
                pass.set_pipeline(&self.pipelines.pack);
                pass.set_bind_group(0, &target.pack_group, &[]);
            }
            pass.dispatch_workgroups((target.width / 2).div_ceil(8), target.height.div_ceil(8), 1);
        }
        encoder.copy_buffer_to_buffer(&target.packed, 0, &target.readback, 0, target.packed.size());
        encoder.finish()
    }

    /// Waits for the frame's commands and copies the YUYV bytes into `frame`.
    fn read_back<const W: usize, const H: usize>(
        &self,
        position: CameraPosition,
        frame: &mut CameraFrame<W, H>,
    ) -> Result<(), RenderError> {
        let target = &self.targets[position.index()];
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

/// Writes `uniform` into `light` with the `casters` whose shadow can fall in `camera`'s view,
/// in the episode's order.
fn write_casters(
    uniform: &mut LightUniform,
    casters: &[Occluder],
    (queue, light): (&wgpu::Queue, &wgpu::Buffer),
    camera: &CameraModel,
) {
    let towards = Vec3::from_slice(&uniform.towards_share[..3]);
    let view_projection = camera.view_projection();
    let mut count = 0;
    for caster in casters {
        if shadow_casters::may_shadow_view(caster, towards, &view_projection) {
            uniform.casters[2 * count] = caster.a.extend(caster.radius).to_array();
            uniform.casters[2 * count + 1] = caster.b.extend(0.0).to_array();
            count += 1;
        }
    }
    uniform.counts[0] = count as u32;
    queue.write_buffer(light, 0, bytemuck::bytes_of(uniform));
}

fn compute_pass<'e>(encoder: &'e mut wgpu::CommandEncoder, label: &str) -> wgpu::ComputePass<'e> {
    encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
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
