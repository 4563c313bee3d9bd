//! The static scene and the ball as triangle meshes in the field frame: carpet, lines, goals
//! and an arena whose four walls differ, so a robot can tell which way it faces; under a
//! venue condition, that episode's walls, features, people, objects and robots.

use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

use crate::conditions::venue::{FigureKind, ROBOT_HEIGHT_M, StandingFigure, VenueLayout};
use crate::field::FieldGeometry;

#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub colour: [f32; 3],
}

/// Triangles, three vertices each.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub vertices: Vec<Vertex>,
}

const CARPET: [f32; 3] = [0.16, 0.48, 0.18];
const FLOOR: [f32; 3] = [0.35, 0.35, 0.33];
const LINE: [f32; 3] = [0.95, 0.95, 0.95];
const POST: [f32; 3] = [0.97, 0.97, 0.97];
const NET: [f32; 3] = [0.72, 0.72, 0.74];
const BOARD: [f32; 3] = [0.22, 0.22, 0.24];
/// Heights above the ground of the layered flat things, to keep depth testing unambiguous.
const CARPET_Z: f32 = 0.002;
const LINE_Z: f32 = 0.004;

impl Mesh {
    fn triangle(&mut self, a: Vec3, b: Vec3, c: Vec3, colour: [f32; 3]) {
        let normal = (b - a).cross(c - a).normalize_or_zero();
        for p in [a, b, c] {
            self.vertices.push(Vertex {
                position: p.to_array(),
                normal: normal.to_array(),
                colour,
            });
        }
    }

    /// A quad a-b-c-d (counter-clockwise seen from its front).
    fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3, colour: [f32; 3]) {
        self.triangle(a, b, c, colour);
        self.triangle(a, c, d, colour);
    }

    /// A flat rectangle on the ground between two corners, at height `z`.
    fn ground_rect(&mut self, min: Vec2, max: Vec2, z: f32, colour: [f32; 3]) {
        self.quad(
            Vec3::new(min.x, min.y, z),
            Vec3::new(max.x, min.y, z),
            Vec3::new(max.x, max.y, z),
            Vec3::new(min.x, max.y, z),
            colour,
        );
    }

    /// A ground line of `width` from `a` to `b`.
    fn ground_line(&mut self, a: Vec2, b: Vec2, width: f32) {
        let along = (b - a).normalize_or_zero();
        let side = Vec2::new(-along.y, along.x) * width / 2.0;
        let at = |p: Vec2| Vec3::new(p.x, p.y, LINE_Z);
        self.quad(at(a - side), at(b - side), at(b + side), at(a + side), LINE);
    }

    /// An axis-aligned box between two corners, all six faces.
    fn cuboid(&mut self, min: Vec3, max: Vec3, colour: [f32; 3]) {
        let corner = |x: bool, y: bool, z: bool| {
            Vec3::new(
                if x { max.x } else { min.x },
                if y { max.y } else { min.y },
                if z { max.z } else { min.z },
            )
        };
        let faces = [
            [(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)],
            [(0, 1, 0), (0, 0, 0), (0, 0, 1), (0, 1, 1)],
            [(1, 1, 0), (0, 1, 0), (0, 1, 1), (1, 1, 1)],
            [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)],
            [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],
            [(0, 1, 0), (1, 1, 0), (1, 0, 0), (0, 0, 0)],
        ];
        for face in faces {
            let [a, b, c, d] = face.map(|(x, y, z)| corner(x == 1, y == 1, z == 1));
            self.quad(a, b, c, d, colour);
        }
    }

    /// A cylinder from `a` to `b` with flat shading per side segment.
    fn cylinder(&mut self, a: Vec3, b: Vec3, radius: f32, segments: usize, colour: [f32; 3]) {
        let axis = (b - a).normalize_or_zero();
        let helper = if axis.z.abs() < 0.9 { Vec3::Z } else { Vec3::X };
        let u = axis.cross(helper).normalize_or_zero();
        let v = axis.cross(u);
        let ring = |i: usize| {
            let angle = i as f32 / segments as f32 * core::f32::consts::TAU;
            (u * angle.cos() + v * angle.sin()) * radius
        };
        for i in 0..segments {
            let (p, q) = (ring(i), ring(i + 1));
            self.quad(a + p, a + q, b + q, b + p, colour);
            self.triangle(b, b + p, b + q, colour);
            self.triangle(a, a + q, a + p, colour);
        }
    }

    /// A box of `half` extents around `centre`, turned by `heading` about the vertical.
    fn turned_box(&mut self, centre: Vec3, half: Vec3, heading: f32, colour: [f32; 3]) {
        let (sin, cos) = heading.sin_cos();
        let corner = |x: f32, y: f32, z: f32| {
            let (lx, ly) = (x * half.x, y * half.y);
            centre + Vec3::new(lx * cos - ly * sin, lx * sin + ly * cos, z * half.z)
        };
        let faces = [
            [(1., -1., -1.), (1., 1., -1.), (1., 1., 1.), (1., -1., 1.)],
            [
                (-1., 1., -1.),
                (-1., -1., -1.),
                (-1., -1., 1.),
                (-1., 1., 1.),
            ],
            [(1., 1., -1.), (-1., 1., -1.), (-1., 1., 1.), (1., 1., 1.)],
            [
                (-1., -1., -1.),
                (1., -1., -1.),
                (1., -1., 1.),
                (-1., -1., 1.),
            ],
            [(-1., -1., 1.), (1., -1., 1.), (1., 1., 1.), (-1., 1., 1.)],
            [
                (-1., 1., -1.),
                (1., 1., -1.),
                (1., -1., -1.),
                (-1., -1., -1.),
            ],
        ];
        for face in faces {
            let [a, b, c, d] = face.map(|(x, y, z)| corner(x, y, z));
            self.quad(a, b, c, d, colour);
        }
    }

    fn ring(&mut self, centre: Vec2, radius: f32, width: f32, segments: usize) {
        for i in 0..segments {
            let angle = |k: usize| k as f32 / segments as f32 * core::f32::consts::TAU;
            let point = |k: usize, r: f32| {
                let a = angle(k);
                Vec3::new(centre.x + r * a.cos(), centre.y + r * a.sin(), LINE_Z)
            };
            let (inner, outer) = (radius - width / 2.0, radius + width / 2.0);
            self.quad(
                point(i, inner),
                point(i, outer),
                point(i + 1, outer),
                point(i + 1, inner),
                LINE,
            );
        }
    }
}

/// Everything that never moves: what stands on the ground and, after it, the ground's layers
/// (carpet, then the floor it lies on), which the renderer draws last with a strict depth
/// test (`Pipelines::ground`).
///
/// Why last: drawn after what stands on them, their hidden fragments fail the depth test
/// before they are shaded and written, and on lavapipe a frame's cost is mostly shading and
/// writing samples (the floor lies under the whole carpet). Why strict: where a layer's depth
/// ties with another surface's (where a wall or a post meets it), the surface drawn first
/// keeps the sample, as when the layers were drawn first and the rest passed on `LessEqual`;
/// every other sample's nearest surface does not depend on the order. So the frames are the
/// same, bit for bit, as with the layers drawn first.
#[derive(Clone, Debug, Default)]
pub struct StaticScene {
    pub mesh: Mesh,
    /// The first vertex of the ground's layers.
    pub ground_start: usize,
}

/// Everything that never moves, in the paper's arena.
pub fn static_scene(field: &FieldGeometry, goal_depth: f32) -> StaticScene {
    static_scene_in(field, goal_depth, &VenueLayout::standard())
}

/// Everything that never moves, in the venue of `layout` (the paper's arena, vertex for
/// vertex, when it is the standard one).
pub fn static_scene_in(
    field: &FieldGeometry,
    goal_depth: f32,
    layout: &VenueLayout,
) -> StaticScene {
    let mut mesh = Mesh::default();
    let (hl, hw) = (field.length / 2.0, field.width / 2.0);
    let (cl, cw) = (hl + field.border, hw + field.border);
    let lw = field.line_width;

    // Lines: the outer edges of the boundary lines lie on the field's dimensions.
    let inset = lw / 2.0;
    let corners = [
        Vec2::new(-hl + inset, -hw + inset),
        Vec2::new(hl - inset, -hw + inset),
        Vec2::new(hl - inset, hw - inset),
        Vec2::new(-hl + inset, hw - inset),
    ];
    for i in 0..4 {
        let extend = (corners[(i + 1) % 4] - corners[i]).normalize() * inset;
        mesh.ground_line(corners[i] - extend, corners[(i + 1) % 4] + extend, lw);
    }
    mesh.ground_line(Vec2::new(0.0, -hw + inset), Vec2::new(0.0, hw - inset), lw);
    mesh.ring(
        Vec2::ZERO,
        field.centre_circle_diameter / 2.0 - inset,
        lw,
        64,
    );
    mesh.ground_line(Vec2::new(-0.05, 0.0), Vec2::new(0.05, 0.0), lw);
    for side in [-1.0f32, 1.0] {
        let goal_line = side * (hl - inset);
        for (depth, half_width) in field.areas() {
            let front = side * (hl - depth + inset);
            mesh.ground_line(
                Vec2::new(front, -half_width),
                Vec2::new(front, half_width),
                lw,
            );
            for y in [-half_width, half_width] {
                mesh.ground_line(Vec2::new(goal_line, y), Vec2::new(front, y), lw);
            }
        }
        let mark = side * (hl - 1.3);
        mesh.ground_line(Vec2::new(mark - 0.05, 0.0), Vec2::new(mark + 0.05, 0.0), lw);
        mesh.ground_line(Vec2::new(mark, -0.05), Vec2::new(mark, 0.05), lw);
        add_goal(&mut mesh, field, side, goal_depth);
    }
    add_arena(&mut mesh, cl, cw, layout);
    for figure in &layout.figures {
        add_figure(&mut mesh, figure);
    }
    // The ground's layers last, the carpet before the floor (StaticScene says why).
    let ground_start = mesh.vertices.len();
    mesh.ground_rect(Vec2::new(-cl, -cw), Vec2::new(cl, cw), CARPET_Z, CARPET);
    mesh.ground_rect(Vec2::new(-14.0, -11.0), Vec2::new(14.0, 11.0), 0.0, FLOOR);
    StaticScene { mesh, ground_start }
}

fn add_goal(mesh: &mut Mesh, field: &FieldGeometry, side: f32, depth: f32) {
    let radius = field.goal_post_diameter / 2.0;
    let top = field.goal_height;
    for (x, y) in field.goal_post_centres(side) {
        mesh.cylinder(Vec3::new(x, y, 0.0), Vec3::new(x, y, top), radius, 12, POST);
    }
    let [(x, left), (_, right)] = field.goal_post_centres(side);
    mesh.cylinder(
        Vec3::new(x, right, top - radius),
        Vec3::new(x, left, top - radius),
        radius,
        12,
        POST,
    );
    let back = x + side * depth;
    let (x_min, x_max) = (x.min(back), x.max(back));
    let net = 0.01;
    mesh.cuboid(
        Vec3::new(x_min, right - net, 0.0),
        Vec3::new(x_max, right, top),
        NET,
    );
    mesh.cuboid(
        Vec3::new(x_min, left, 0.0),
        Vec3::new(x_max, left + net, top),
        NET,
    );
    let back_outer = back + side * net;
    mesh.cuboid(
        Vec3::new(back.min(back_outer), right, 0.0),
        Vec3::new(back.max(back_outer), left, top),
        NET,
    );
    mesh.cuboid(
        Vec3::new(x_min, right, top - net),
        Vec3::new(x_max, left, top),
        NET,
    );
}

/// Boards around the carpet, and four different walls further out: in the paper's arena the
/// +x wall blue with white stripes, the -x wall orange with dark blocks, the +y wall pale
/// yellow with windows, the -y wall violet with pillars; in another venue its own walls and
/// features.
fn add_arena(mesh: &mut Mesh, cl: f32, cw: f32, layout: &VenueLayout) {
    let board = 0.05;
    let height = 0.3;
    for side in [-1.0f32, 1.0] {
        let y = side * (cw + board);
        mesh.cuboid(
            Vec3::new(-cl - 2.0 * board, y - board, 0.0),
            Vec3::new(cl + 2.0 * board, y + board, height),
            BOARD,
        );
        let x = side * (cl + board);
        mesh.cuboid(
            Vec3::new(x - board, -cw, 0.0),
            Vec3::new(x + board, cw, height),
            BOARD,
        );
    }
    let (wx, wy, wall_height) = (layout.wall_x, layout.wall_y, layout.wall_height);
    let [blue, orange, yellow, violet] = layout.walls;
    // Walls face the field; a wall is a thin box.
    mesh.cuboid(
        Vec3::new(wx, -wy, 0.0),
        Vec3::new(wx + 0.1, wy, wall_height),
        blue,
    );
    mesh.cuboid(
        Vec3::new(-wx - 0.1, -wy, 0.0),
        Vec3::new(-wx, wy, wall_height),
        orange,
    );
    mesh.cuboid(
        Vec3::new(-wx, wy, 0.0),
        Vec3::new(wx, wy + 0.1, wall_height),
        yellow,
    );
    mesh.cuboid(
        Vec3::new(-wx, -wy - 0.1, 0.0),
        Vec3::new(wx, -wy, wall_height),
        violet,
    );
    for &(min, max, colour) in &layout.features {
        mesh.cuboid(min, max, colour);
    }
    if !layout.paper_features {
        return;
    }
    // Features in front of the walls.
    let mut i = 0;
    let mut y = -wy + 0.5;
    while y < wy - 0.5 {
        mesh.cuboid(
            Vec3::new(wx - 0.02, y, 0.2),
            Vec3::new(wx, y + 0.25, wall_height - 0.2),
            [0.95, 0.95, 0.95],
        );
        let block = if i % 2 == 0 {
            [0.2, 0.15, 0.1]
        } else {
            [0.55, 0.25, 0.05]
        };
        mesh.cuboid(
            Vec3::new(-wx, y, 0.5),
            Vec3::new(-wx + 0.02, y + 0.6, 1.4),
            block,
        );
        y += 1.3;
        i += 1;
    }
    let mut x = -wx + 0.8;
    while x < wx - 0.8 {
        mesh.cuboid(
            Vec3::new(x, wy - 0.02, 1.0),
            Vec3::new(x + 1.0, wy, 1.8),
            [0.55, 0.7, 0.85],
        );
        mesh.cuboid(
            Vec3::new(x, -wy, 0.0),
            Vec3::new(x + 0.3, -wy + 0.3, wall_height),
            [0.25, 0.18, 0.35],
        );
        x += 2.4;
    }
}

/// A person, a robot or an object standing on the floor: boxes turned to its heading, each
/// placed by its centre (forward and left of the figure's position, height) and half sizes.
fn add_figure(mesh: &mut Mesh, figure: &StandingFigure) {
    let (sin, cos) = figure.heading.sin_cos();
    let at = |forward: f32, left: f32, z: f32| {
        figure.position.extend(z)
            + Vec3::new(forward * cos - left * sin, forward * sin + left * cos, 0.0)
    };
    let heading = figure.heading;
    let mut part = |(forward, left, z): (f32, f32, f32), half: [f32; 3], colour: [f32; 3]| {
        mesh.turned_box(at(forward, left, z), Vec3::from(half), heading, colour);
    };
    let (colour, second) = (figure.colour, figure.second_colour);
    match figure.kind {
        FigureKind::Person { height_m: h } => {
            let skin = [0.78, 0.6, 0.48];
            for side in [-1.0, 1.0] {
                part(
                    (0.0, side * 0.09, 0.235 * h),
                    [0.08, 0.07, 0.235 * h],
                    second,
                );
                part((0.0, side * 0.25, 0.64 * h), [0.05, 0.05, 0.17 * h], colour);
            }
            part((0.0, 0.0, 0.645 * h), [0.11, 0.2, 0.175 * h], colour);
            part((0.0, 0.0, 0.91 * h), [0.1, 0.085, 0.09 * h], skin);
        }
        FigureKind::Robot => {
            let white = [0.9, 0.9, 0.9];
            let h = ROBOT_HEIGHT_M;
            for side in [-1.0, 1.0] {
                part((0.02, side * 0.05, 0.02), [0.08, 0.045, 0.02], white);
                part((0.0, side * 0.05, 0.17), [0.045, 0.04, 0.13], second);
                part((0.0, side * 0.12, 0.36), [0.035, 0.03, 0.09], white);
            }
            part((0.0, 0.0, 0.375), [0.06, 0.08, 0.075], white);
            part((0.045, 0.0, 0.37), [0.02, 0.07, 0.06], colour);
            part((0.0, 0.0, h - 0.065), [0.06, 0.065, 0.065], white);
            part((0.055, 0.0, h - 0.06), [0.01, 0.045, 0.02], second);
        }
        FigureKind::Object { size } => {
            part((0.0, 0.0, size.z / 2.0), (size / 2.0).to_array(), colour);
        }
    }
}

/// A ball of `radius` around the origin, white with black patches at the twelve pentagon
/// centres of a football, so its rolling shows.
pub fn ball_mesh(radius: f32) -> Mesh {
    let golden = (1.0 + 5.0f32.sqrt()) / 2.0;
    let mut patches = Vec::new();
    for (a, b) in [
        (1.0f32, golden),
        (-1.0, golden),
        (1.0, -golden),
        (-1.0, -golden),
    ] {
        patches.push(Vec3::new(0.0, a, b).normalize());
        patches.push(Vec3::new(a, b, 0.0).normalize());
        patches.push(Vec3::new(b, 0.0, a).normalize());
    }
    let colour = |direction: Vec3| {
        if patches.iter().any(|p| p.dot(direction) > 0.93) {
            [0.08, 0.08, 0.08]
        } else {
            [0.97, 0.97, 0.97]
        }
    };
    let (rings, segments) = (16, 24);
    let point = |ring: usize, segment: usize| {
        let polar = ring as f32 / rings as f32 * core::f32::consts::PI;
        let azimuth = segment as f32 / segments as f32 * core::f32::consts::TAU;
        Vec3::new(
            polar.sin() * azimuth.cos(),
            polar.sin() * azimuth.sin(),
            polar.cos(),
        )
    };
    let mut mesh = Mesh::default();
    for ring in 0..rings {
        for segment in 0..segments {
            let corners = [
                point(ring, segment),
                point(ring + 1, segment),
                point(ring + 1, segment + 1),
                point(ring, segment + 1),
            ];
            let centre = (corners[0] + corners[1] + corners[2] + corners[3]).normalize_or_zero();
            let c = colour(centre);
            for tri in [[0, 1, 2], [0, 2, 3]] {
                for k in tri {
                    mesh.vertices.push(Vertex {
                        position: (corners[k] * radius).to_array(),
                        normal: corners[k].to_array(),
                        colour: c,
                    });
                }
            }
        }
    }
    mesh
}
