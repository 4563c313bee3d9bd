//! The pipelines of a frame and the bind group layouts they share with the cameras'
//! targets: the flat and the lit scene (render), YUYV packing, linear light and the camera
//! effects (compute); and the helpers that describe them.

use super::{COLOUR_FORMAT, CameraEffects, DEPTH_FORMAT, LINEAR_FORMAT, LightUniform, Vertex};

/// The bind group layouts of the pipelines, which the targets' and the renderer's bind
/// groups are made with.
pub(super) struct Layouts {
    pub(super) camera: wgpu::BindGroupLayout,
    pub(super) model: wgpu::BindGroupLayout,
    pub(super) light: wgpu::BindGroupLayout,
    pub(super) pack: wgpu::BindGroupLayout,
    pub(super) linear: wgpu::BindGroupLayout,
    pub(super) effects: wgpu::BindGroupLayout,
}

/// Every pipeline a frame may use.
pub(super) struct Pipelines {
    /// The clean scene: flat colours, soft light (`scene.wgsl`).
    pub(super) scene: wgpu::RenderPipeline,
    /// The same for the ground's layers, drawn last with a strict depth test (`StaticScene`).
    pub(super) ground: wgpu::RenderPipeline,
    /// The scene under a directional light with shadows and bright spots (`scene_lit.wgsl`).
    pub(super) lit: wgpu::RenderPipeline,
    /// The same for the ground's layers.
    pub(super) lit_ground: wgpu::RenderPipeline,
    /// The resolved image packed into YUYV (`yuyv.wgsl`).
    pub(super) pack: wgpu::ComputePipeline,
    /// The resolved image in linear light, for the effects (`linear_light.wgsl`).
    pub(super) linear: wgpu::ComputePipeline,
    /// The camera's effects, then YUYV (`camera_effects.wgsl`): one pipeline per
    /// combination of optional stages, each built the first time a frame needs it.
    effects: EffectsPipelines,
}

/// Which optional stages of the effects shader (`camera_effects.wgsl`'s override constants)
/// a frame needs: a stage is left out only where its runtime condition in the shader is
/// false for every pixel of the frame, so the frame comes out the same bit for bit, and
/// lavapipe, which runs both sides of every branch under a lane mask, does not pay for it.
///
/// A frame whose camera turns keeps the lens stage: with it left out, LLVM compiles the
/// turn's sample positions otherwise, and some motion-blurred frames changed in their last
/// bits (`render_cost`, seeds 10001 and 20007 under motion-blur:3 and :5). With that rule the
/// frames of every condition measured, `randomized` included, came out the same.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct EffectsStages {
    /// Read or shot noise (`gain_contrast_noise.z` or `.w` positive).
    pub(super) noise: bool,
    /// The camera turns during the exposure (an angular velocity that is not zero: the
    /// rotation of every sample is zero otherwise).
    pub(super) turn: bool,
    /// A softer lens (softness positive).
    pub(super) soft_lens: bool,
}

impl EffectsStages {
    const COMBINATIONS: usize = 8;

    /// The stages `effects` needs, decided with the shader's own comparisons.
    pub(super) fn of(effects: &CameraEffects) -> Self {
        let [_, _, read, shot] = effects.gain_contrast_noise;
        let [x, y, z, _] = effects.omega_exposure;
        let turn = x != 0.0 || y != 0.0 || z != 0.0;
        Self {
            noise: read > 0.0 || shot > 0.0,
            turn,
            soft_lens: turn || effects.readout_vignetting_softness_samples[2] > 0.0,
        }
    }

    fn index(self) -> usize {
        usize::from(self.noise) | usize::from(self.turn) << 1 | usize::from(self.soft_lens) << 2
    }

    /// The shader's override constants for these stages.
    fn constants(self) -> [(&'static str, f64); 3] {
        let flag = |on: bool| if on { 1.0 } else { 0.0 };
        [
            ("NOISE", flag(self.noise)),
            ("TURN", flag(self.turn)),
            ("SOFT_LENS", flag(self.soft_lens)),
        ]
    }
}

/// The effects shader's pipelines, one per [`EffectsStages`], built on first use (an
/// episode needs one to four of the six; each costs a compilation).
struct EffectsPipelines {
    shader: wgpu::ShaderModule,
    layout: wgpu::PipelineLayout,
    built: [std::sync::OnceLock<wgpu::ComputePipeline>; EffectsStages::COMBINATIONS],
}

impl EffectsPipelines {
    fn new(device: &wgpu::Device, layout: &wgpu::BindGroupLayout) -> Self {
        let label = Some("camera effects");
        Self {
            shader: device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label,
                source: wgpu::ShaderSource::Wgsl(
                    concat!(
                        include_str!("yuyv_pair.wgsl"),
                        include_str!("camera_effects.wgsl")
                    )
                    .into(),
                ),
            }),
            layout: device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label,
                bind_group_layouts: &[Some(layout)],
                ..Default::default()
            }),
            built: Default::default(),
        }
    }

    fn get(&self, device: &wgpu::Device, stages: EffectsStages) -> &wgpu::ComputePipeline {
        self.built[stages.index()].get_or_init(|| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("camera effects"),
                layout: Some(&self.layout),
                module: &self.shader,
                entry_point: Some("effects_main"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &stages.constants(),
                    ..Default::default()
                },
                cache: None,
            })
        })
    }
}

impl Pipelines {
    /// Compiles every pipeline of a frame on `device`.
    pub(super) fn new(device: &wgpu::Device, samples: u32) -> (Layouts, Self) {
        let camera_layout = uniform_layout(device, "camera", false);
        let model_layout = uniform_layout(device, "model", true);
        let scene_layouts = [&camera_layout, &model_layout];
        let scene_source = concat!(
            include_str!("scene_vertex.wgsl"),
            include_str!("scene.wgsl")
        );
        let scene_pipeline = render_pipeline(
            device,
            "scene",
            scene_source,
            &scene_layouts,
            (STANDING, samples),
        );
        let ground_pipeline = render_pipeline(
            device,
            "ground",
            scene_source,
            &scene_layouts,
            (GROUND, samples),
        );
        let light_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("light"),
            entries: &read_twice_entries(
                0,
                wgpu::ShaderStages::FRAGMENT,
                size_of::<LightUniform>(),
            ),
        });
        let lit_layouts = [&camera_layout, &model_layout, &light_layout];
        let lit_source = concat!(
            include_str!("scene_vertex.wgsl"),
            include_str!("scene_lit.wgsl")
        );
        let lit_pipeline = render_pipeline(
            device,
            "lit scene",
            lit_source,
            &lit_layouts,
            (STANDING, samples),
        );
        let lit_ground = render_pipeline(
            device,
            "lit ground",
            lit_source,
            &lit_layouts,
            (GROUND, samples),
        );
        let [effects_uniform, effects_storage] =
            read_twice_entries(2, wgpu::ShaderStages::COMPUTE, size_of::<CameraEffects>());
        let effects_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("effects"),
            entries: &[
                image_entry(),
                packed_entry(),
                effects_uniform,
                effects_storage,
            ],
        });
        let effects_pipelines = EffectsPipelines::new(device, &effects_layout);
        let linear_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("linear light"),
            entries: &[
                image_entry(),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: LINEAR_FORMAT,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                    count: None,
                },
            ],
        });
        let linear_pipeline = compute_pipeline(
            device,
            "linear light",
            include_str!("linear_light.wgsl"),
            "linear_main",
            &linear_layout,
        );
        let pack_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("pack"),
            entries: &[image_entry(), packed_entry()],
        });
        let pack_pipeline = compute_pipeline(
            device,
            "yuyv",
            concat!(include_str!("yuyv_pair.wgsl"), include_str!("yuyv.wgsl")),
            "pack_main",
            &pack_layout,
        );

        let layouts = Layouts {
            camera: camera_layout,
            model: model_layout,
            light: light_layout,
            pack: pack_layout,
            linear: linear_layout,
            effects: effects_layout,
        };
        let pipelines = Self {
            scene: scene_pipeline,
            ground: ground_pipeline,
            lit: lit_pipeline,
            lit_ground,
            pack: pack_pipeline,
            linear: linear_pipeline,
            effects: effects_pipelines,
        };
        (layouts, pipelines)
    }
}

impl Pipelines {
    /// The effects pipeline with `stages` (built now if no frame needed it before).
    pub(super) fn effects(
        &self,
        device: &wgpu::Device,
        stages: EffectsStages,
    ) -> &wgpu::ComputePipeline {
        self.effects.get(device, stages)
    }
}

pub(super) fn uniform_layout(
    device: &wgpu::Device,
    label: &str,
    dynamic: bool,
) -> wgpu::BindGroupLayout {
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

/// The depth test of what stands on the ground (and the ball): a later surface at the same
/// depth wins.
const STANDING: wgpu::CompareFunction = wgpu::CompareFunction::LessEqual;
/// The depth test of the ground's layers, drawn last: a surface drawn before keeps a tie.
const GROUND: wgpu::CompareFunction = wgpu::CompareFunction::Less;

pub(super) fn render_pipeline(
    device: &wgpu::Device,
    label: &str,
    source: &str,
    layouts: &[&wgpu::BindGroupLayout],
    (depth_compare, samples): (wgpu::CompareFunction, u32),
) -> wgpu::RenderPipeline {
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let layouts: Vec<Option<&wgpu::BindGroupLayout>> = layouts.iter().map(|l| Some(*l)).collect();
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &layouts,
        ..Default::default()
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
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
            depth_compare: Some(depth_compare),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: wgpu::MultisampleState {
            count: samples,
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

pub(super) fn compute_pipeline(
    device: &wgpu::Device,
    label: &str,
    source: &str,
    entry_point: &str,
    layout: &wgpu::BindGroupLayout,
) -> wgpu::ComputePipeline {
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &[Some(layout)],
        ..Default::default()
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: Some(&pipeline_layout),
        module: &shader,
        entry_point: Some(entry_point),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// How the light and effects buffers are used: each is bound twice, as a uniform buffer
/// for the arithmetic and as a read-only storage buffer for what decides control flow (see
/// `scene_lit.wgsl`: lavapipe loads a uniform value once a group, but keeps a shader variant
/// per distinct uniform value its branches and loops read).
pub(super) const READ_TWICE: wgpu::BufferUsages = wgpu::BufferUsages::UNIFORM
    .union(wgpu::BufferUsages::STORAGE)
    .union(wgpu::BufferUsages::COPY_DST);

/// The two bindings of a [`READ_TWICE`] buffer of `size` bytes: the uniform one at `first`,
/// the read-only storage alias at `first + 1`.
pub(super) fn read_twice_entries(
    first: u32,
    visibility: wgpu::ShaderStages,
    size: usize,
) -> [wgpu::BindGroupLayoutEntry; 2] {
    [false, true].map(|storage| wgpu::BindGroupLayoutEntry {
        binding: first + u32::from(storage),
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: if storage {
                wgpu::BufferBindingType::Storage { read_only: true }
            } else {
                wgpu::BufferBindingType::Uniform
            },
            has_dynamic_offset: false,
            min_binding_size: wgpu::BufferSize::new(size as u64),
        },
        count: None,
    })
}

/// The resolved image a compute pass reads (binding 0).
pub(super) fn image_entry() -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding: 0,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

/// The YUYV buffer a compute pass writes (binding 1).
pub(super) fn packed_entry() -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding: 1,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: false },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conditions::Conditions;
    use glam::Quat;

    /// The effects of frame 5 of seed 7 under `conditions`, the camera having turned by
    /// `turn_rad` about its vertical axis since the frame before (1/30 s earlier).
    fn stages(conditions: &str, turn_rad: f32) -> EffectsStages {
        let conditions: Conditions = conditions.parse().expect("conditions");
        let plan = conditions.resolve(7).camera;
        let before = Quat::IDENTITY;
        let now = Quat::from_rotation_z(turn_rad);
        let effects = plan.frame(
            0,
            5,
            0.2,
            now,
            Some((before, 1.0 / 30.0)),
            (640, 480),
            (550.0, 550.0),
        );
        EffectsStages::of(&effects)
    }

    const NONE: EffectsStages = EffectsStages {
        noise: false,
        turn: false,
        soft_lens: false,
    };

    #[test]
    fn a_stage_stays_where_a_frame_may_take_it() {
        assert_eq!(stages("contrast:3,exposure:5,white-balance:2", 0.1), NONE);
        assert_eq!(
            stages("noise:1", 0.0),
            EffectsStages {
                noise: true,
                ..NONE
            }
        );
        assert_eq!(
            stages("lens:1", 0.0),
            EffectsStages {
                soft_lens: true,
                ..NONE
            }
        );
        // A still camera needs no turn even with a long exposure.
        assert_eq!(stages("motion-blur:5", 0.0), NONE);
        // A turning one keeps the lens stage too (see `EffectsStages`).
        assert_eq!(
            stages("motion-blur:1", 0.05),
            EffectsStages {
                turn: true,
                soft_lens: true,
                ..NONE
            }
        );
    }

    #[test]
    fn every_combination_has_its_own_pipeline() {
        let mut indices = std::collections::BTreeSet::new();
        for bits in 0..8u8 {
            let stages = EffectsStages {
                noise: bits & 1 != 0,
                turn: bits & 2 != 0,
                soft_lens: bits & 4 != 0,
            };
            assert!(stages.index() < EffectsStages::COMBINATIONS);
            indices.insert(stages.index());
        }
        assert_eq!(indices.len(), EffectsStages::COMBINATIONS);
    }
}
