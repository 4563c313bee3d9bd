//! The venue around the field and the light on it, drawn from an episode's seed: walls,
//! their colours and features; people and objects beyond the field lines; robots standing
//! around the field and on its edge; a directional light with shadows and bright spots.
//!
//! Two venue families: the *hall* (flat walls of any colour with banners, windows, pillars
//! and doors, people and things standing about), which training may draw, and the *stadium*
//! (tiers of seated spectators, dark walls, striped advertising boards, floodlight panels),
//! which it never does: the measure of a venue never seen.
//!
//! Everything here is geometry and colour; the renderer builds its meshes from it, and a
//! teacher that sees as a detector does reads the [`Occluder`]s.

use glam::{Vec2, Vec3};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use super::{Condition, Conditions, Severity};
use crate::field::FieldGeometry;

/// Which arena surrounds the field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VenueStyle {
    /// The paper's render: four walls, each its own colour, the same in every episode.
    Standard,
    /// A hall drawn from the seed (the family training may see).
    Hall,
    /// A stadium drawn from the seed (never in training).
    Stadium,
}

/// What stands somewhere: a person, a robot or a box-shaped thing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FigureKind {
    /// A person of the given height, metres.
    Person { height_m: f32 },
    /// A Nao-sized robot (0.57 m).
    Robot,
    /// A box (a table, a bag, a case) of the given size, metres.
    Object { size: Vec3 },
}

/// A figure standing on the ground at `position` (field frame), facing `heading`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StandingFigure {
    pub kind: FigureKind,
    pub position: Vec2,
    pub heading: f32,
    /// Main colour (clothes, jersey, the object's colour) and a second one.
    pub colour: [f32; 3],
    pub second_colour: [f32; 3],
}

/// A Nao's height, metres.
pub const ROBOT_HEIGHT_M: f32 = 0.57;

impl StandingFigure {
    /// What of it blocks a line of sight, as capsules (a segment and a radius).
    pub fn occluders(&self) -> Vec<Occluder> {
        let at = |z: f32| self.position.extend(z);
        match self.kind {
            FigureKind::Person { height_m } => vec![
                Occluder::new(at(0.2), at(height_m - 0.35), 0.2),
                Occluder::new(at(height_m - 0.12), at(height_m - 0.12), 0.11),
            ],
            FigureKind::Robot => vec![
                Occluder::new(at(0.08), at(0.38), 0.1),
                Occluder::new(at(0.47), at(0.5), 0.065),
            ],
            FigureKind::Object { size } => {
                let radius = 0.5 * size.x.min(size.y);
                vec![Occluder::new(
                    at(radius.min(size.z / 2.0)),
                    at((size.z - radius).max(size.z / 2.0)),
                    radius,
                )]
            }
        }
    }
}

/// Something that blocks lines of sight and casts a shadow: the points within `radius` of
/// the segment `a`-`b` (a sphere when `a == b`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Occluder {
    pub a: Vec3,
    pub b: Vec3,
    pub radius: f32,
}

impl Occluder {
    pub fn new(a: Vec3, b: Vec3, radius: f32) -> Self {
        Self { a, b, radius }
    }

    /// Whether the straight segment from `from` to `to` passes through it.
    pub fn blocks(&self, from: Vec3, to: Vec3) -> bool {
        segment_distance(from, to, self.a, self.b) < self.radius
    }
}

/// The shortest distance between segments `p0`-`p1` and `q0`-`q1`.
pub fn segment_distance(p0: Vec3, p1: Vec3, q0: Vec3, q1: Vec3) -> f32 {
    let (d1, d2, r) = (p1 - p0, q1 - q0, p0 - q0);
    let (a, e, f) = (d1.dot(d1), d2.dot(d2), d2.dot(r));
    let (s, t) = if a <= 1e-12 && e <= 1e-12 {
        (0.0, 0.0)
    } else if a <= 1e-12 {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(r);
        if e <= 1e-12 {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(d2);
            let denominator = a * e - b * b;
            let mut s = if denominator > 1e-12 {
                ((b * f - c * e) / denominator).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    ((p0 + d1 * s) - (q0 + d2 * t)).length()
}

/// The goals' posts and crossbars as occluders.
pub fn goal_occluders(field: &FieldGeometry) -> Vec<Occluder> {
    let radius = field.goal_post_diameter / 2.0;
    let top = field.goal_height;
    let mut occluders = Vec::new();
    for side in [-1.0f32, 1.0] {
        let posts = field.goal_post_centres(side);
        for (x, y) in posts {
            occluders.push(Occluder::new(
                Vec3::new(x, y, 0.0),
                Vec3::new(x, y, top),
                radius,
            ));
        }
        let [(x, left), (_, right)] = posts;
        occluders.push(Occluder::new(
            Vec3::new(x, right, top - radius),
            Vec3::new(x, left, top - radius),
            radius,
        ));
    }
    occluders
}

/// A directional light (the sun through a roof or windows) and bright spots on the field.
#[derive(Clone, Debug, PartialEq)]
pub struct Sunlight {
    /// Unit vector towards the light, field frame.
    pub towards: Vec3,
    /// The share of a lit surface's light that comes from this light: what a shadow takes.
    pub share: f32,
    /// Bright spots on the field: centre, half axes (metres, along and across `angle`), the
    /// axis angle and how much brighter the spot is (0.5: half as bright again).
    pub spots: Vec<BrightSpot>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrightSpot {
    pub centre: Vec2,
    pub half_axes: Vec2,
    pub angle: f32,
    pub gain: f32,
}

/// Walls (+x, -x, +y, -y), their features (boxes in front of them), what stands about, the
/// colour above the walls and the light.
#[derive(Clone, Debug, PartialEq)]
pub struct VenueLayout {
    pub style: VenueStyle,
    pub walls: [[f32; 3]; 4],
    /// The walls' distance from the centre along x and y, and their height, metres.
    pub wall_x: f32,
    pub wall_y: f32,
    pub wall_height: f32,
    /// Boxes: minimum corner, maximum corner, colour.
    pub features: Vec<(Vec3, Vec3, [f32; 3])>,
    /// Whether the paper's wall features (stripes, blocks, windows, pillars) are drawn.
    pub paper_features: bool,
    pub figures: Vec<StandingFigure>,
    /// Above the walls (the colour the image is cleared to).
    pub sky: [f64; 3],
    pub sunlight: Option<Sunlight>,
}

/// The paper's arena's colours (the renderer builds its walls from a layout).
const STANDARD_WALLS: [[f32; 3]; 4] = [
    [0.15, 0.3, 0.7],
    [0.85, 0.45, 0.12],
    [0.85, 0.8, 0.55],
    [0.45, 0.3, 0.6],
];
const STANDARD_SKY: [f64; 3] = [0.78, 0.8, 0.84];
/// The SPL field inside its lines, half length and half width, and the carpet's border.
const HALF_LENGTH: f32 = 4.5;
const HALF_WIDTH: f32 = 3.0;
const BORDER: f32 = 0.7;

impl VenueLayout {
    pub fn standard() -> Self {
        Self {
            style: VenueStyle::Standard,
            walls: STANDARD_WALLS,
            wall_x: 8.0,
            wall_y: 6.0,
            wall_height: 2.2,
            features: Vec::new(),
            paper_features: true,
            figures: Vec::new(),
            sky: STANDARD_SKY,
            sunlight: None,
        }
    }

    /// Whether anything differs from the paper's arena (its mesh is then built anew).
    pub fn is_standard(&self) -> bool {
        *self == Self::standard()
    }

    pub(super) fn draw(conditions: &Conditions, stream: impl Fn(Condition) -> ChaCha8Rng) -> Self {
        let mut layout = Self::standard();
        if let Some(severity) = conditions.severity(Condition::Venue) {
            layout.draw_hall(severity, &mut stream(Condition::Venue));
        } else if let Some(severity) = conditions.severity(Condition::UnseenVenue) {
            layout.draw_stadium(severity, &mut stream(Condition::UnseenVenue));
        }
        if let Some(severity) = conditions.severity(Condition::Robots) {
            layout.draw_robots(severity, &mut stream(Condition::Robots));
        }
        if let Some(severity) = conditions.severity(Condition::Light) {
            layout.sunlight = Some(draw_sunlight(severity, &mut stream(Condition::Light)));
        }
        layout
    }

    /// Everything that can hide the ball or cast a shadow besides the goals and the ball.
    pub fn occluders(&self) -> Vec<Occluder> {
        self.figures
            .iter()
            .flat_map(StandingFigure::occluders)
            .collect()
    }

    fn draw_hall(&mut self, severity: Severity, rng: &mut ChaCha8Rng) {
        self.style = VenueStyle::Hall;
        let level = severity.level();
        if level == 1 {
            // The paper's walls, their colours moved a little.
            for wall in &mut self.walls {
                *wall = wall.map(|c| (c + rng.random_range(-0.12..0.12)).clamp(0.02, 0.98));
            }
        } else {
            self.paper_features = false;
            for wall in &mut self.walls {
                *wall = random_colour(rng, 0.1..0.9);
            }
            self.wall_x = rng.random_range(6.5..9.5);
            self.wall_y = rng.random_range(5.0..8.0);
            self.wall_height = rng.random_range(2.0..4.0);
            self.sky = random_colour(rng, 0.5..0.95).map(f64::from);
        }
        let (wx, wy, height) = (self.wall_x, self.wall_y, self.wall_height);
        // Banners, windows, doors and pillars on random walls.
        for _ in 0..severity.pick([2, 4, 6, 9, 12]) {
            let wall = rng.random_range(0..4usize);
            let (width, tall) = (rng.random_range(0.4..2.5), rng.random_range(0.4..1.8));
            let bottom = rng.random_range(0.0..(height - tall).max(0.01));
            let kind = rng.random_range(0..4);
            let colour = match kind {
                0 => [0.8, 0.88, 0.95], // a window, bright
                1 => [0.3, 0.22, 0.15], // a door, dark
                _ => random_colour(rng, 0.05..0.95),
            };
            let (z0, z1) = if kind == 1 {
                (0.0, 2.0f32.min(height))
            } else {
                (bottom, bottom + tall)
            };
            let along = rng.random_range(-1.0..1.0);
            let feature = match wall {
                0 | 1 => {
                    let x = if wall == 0 { wx } else { -wx };
                    let y = along * (wy - width);
                    let inward = -x.signum() * 0.03;
                    (
                        Vec3::new(x.min(x + inward), y, z0),
                        Vec3::new(x.max(x + inward), y + width, z1),
                    )
                }
                _ => {
                    let y = if wall == 2 { wy } else { -wy };
                    let x = along * (wx - width);
                    let inward = -y.signum() * 0.03;
                    (
                        Vec3::new(x, y.min(y + inward), z0),
                        Vec3::new(x + width, y.max(y + inward), z1),
                    )
                }
            };
            self.features.push((feature.0, feature.1, colour));
        }
        // People and things beyond the carpet, nearer at the harsher severities.
        let people = severity.pick([0, 2, 5, 9, 14]);
        let objects = severity.pick([0, 1, 3, 5, 7]);
        let nearest = severity.pick([1.5, 1.2, 0.9, 0.6, 0.3]);
        for i in 0..people + objects {
            let position = beyond_the_carpet(rng, nearest, self.wall_x - 0.5, self.wall_y - 0.5);
            let kind = if i < people {
                FigureKind::Person {
                    height_m: rng.random_range(1.5..1.95),
                }
            } else {
                FigureKind::Object {
                    size: Vec3::new(
                        rng.random_range(0.3..1.4),
                        rng.random_range(0.3..0.9),
                        rng.random_range(0.2..1.0),
                    ),
                }
            };
            self.figures.push(StandingFigure {
                kind,
                position,
                heading: rng.random_range(-core::f32::consts::PI..core::f32::consts::PI),
                colour: random_colour(rng, 0.05..0.95),
                second_colour: random_colour(rng, 0.05..0.6),
            });
        }
    }

    fn draw_stadium(&mut self, severity: Severity, rng: &mut ChaCha8Rng) {
        self.style = VenueStyle::Stadium;
        self.paper_features = false;
        let dark = rng.random_range(0.03..0.15);
        self.walls = [[dark, dark, dark + rng.random_range(0.0..0.1)]; 4];
        self.wall_x = rng.random_range(9.0..11.0);
        self.wall_y = rng.random_range(8.0..10.0);
        self.wall_height = rng.random_range(4.0..6.0);
        self.sky = [f64::from(dark) * 0.5; 3];
        let (wx, wy) = (self.wall_x, self.wall_y);
        // Tiers along both long sides and behind the goals, from the carpet's edge outwards.
        let rows = severity.pick([2, 3, 4, 5, 6]);
        let tier_colour = random_colour(rng, 0.2..0.6);
        for side in [-1.0f32, 1.0] {
            for row in 0..rows {
                let step = row as f32;
                let near = HALF_WIDTH + BORDER + 1.2 + 0.8 * step;
                let (y0, y1) = (side * near, side * (near + 0.8));
                self.features.push((
                    Vec3::new(-wx + 0.5, y0.min(y1), 0.0),
                    Vec3::new(wx - 0.5, y0.max(y1), 0.35 * (step + 1.0)),
                    tier_colour,
                ));
            }
        }
        // Spectators seated on the tiers (a box each), denser at the harsher severities.
        let share = severity.pick([0.15, 0.3, 0.45, 0.6, 0.8]);
        for side in [-1.0f32, 1.0] {
            for row in 0..rows {
                let step = row as f32;
                let y = side * (HALF_WIDTH + BORDER + 1.6 + 0.8 * step);
                let mut x = -wx + 0.8;
                while x < wx - 0.8 {
                    if rng.random_bool(share) {
                        let colour = random_colour(rng, 0.05..0.95);
                        let seat = 0.35 * (step + 1.0);
                        self.features.push((
                            Vec3::new(x, y - 0.2, seat),
                            Vec3::new(x + 0.4, y + 0.2, seat + 0.8),
                            colour,
                        ));
                        self.features.push((
                            Vec3::new(x + 0.1, y - 0.1, seat + 0.8),
                            Vec3::new(x + 0.3, y + 0.1, seat + 1.05),
                            [0.75, 0.55, 0.42],
                        ));
                    }
                    x += 0.55;
                }
            }
        }
        // Striped advertising boards around the carpet, floodlight panels on the walls.
        let boards = severity.pick([2, 4, 6, 8, 10]);
        for b in 0..boards {
            let side = if b % 2 == 0 { 1.0 } else { -1.0 };
            let x0 = -HALF_LENGTH + (b / 2) as f32 * 2.2 - 0.5;
            let y = side * (HALF_WIDTH + BORDER + 0.6);
            let (first, second) = (random_colour(rng, 0.6..0.98), random_colour(rng, 0.02..0.3));
            for stripe in 0..6 {
                let x = x0 + stripe as f32 * 0.3;
                self.features.push((
                    Vec3::new(x, y - 0.05, 0.0),
                    Vec3::new(x + 0.3, y + 0.05, 0.8),
                    if stripe % 2 == 0 { first } else { second },
                ));
            }
        }
        for i in 0..4 {
            let x = -wx + (i as f32 + 0.5) * wx / 2.0;
            for side in [-1.0f32, 1.0] {
                let y = side * wy;
                self.features.push((
                    Vec3::new(x - 0.6, y.min(y - side * 0.03), self.wall_height - 1.2),
                    Vec3::new(x + 0.6, y.max(y - side * 0.03), self.wall_height - 0.4),
                    [0.98, 0.98, 0.92],
                ));
            }
        }
    }

    fn draw_robots(&mut self, severity: Severity, rng: &mut ChaCha8Rng) {
        let count = severity.pick([1, 2, 4, 6, 8]);
        // From this far outside the field lines (negative: on the line) to 0.6 m beyond.
        let nearest = severity.pick([0.3, 0.2, 0.1, 0.0, -0.1]);
        for _ in 0..count {
            let beyond = rng.random_range(nearest..0.6);
            let along = rng.random_range(-1.0f32..1.0);
            let position = match rng.random_range(0..4) {
                0 => Vec2::new(along * HALF_LENGTH, HALF_WIDTH + beyond),
                1 => Vec2::new(along * HALF_LENGTH, -HALF_WIDTH - beyond),
                // Beside the goals, never in them.
                2 => Vec2::new(HALF_LENGTH + beyond, side_of_goal(rng)),
                _ => Vec2::new(-HALF_LENGTH - beyond, side_of_goal(rng)),
            };
            let jersey = if rng.random_bool(0.5) {
                random_colour(rng, 0.1..0.9)
            } else {
                [0.1, 0.1, 0.1]
            };
            self.figures.push(StandingFigure {
                kind: FigureKind::Robot,
                position,
                heading: rng.random_range(-core::f32::consts::PI..core::f32::consts::PI),
                colour: jersey,
                second_colour: [0.55, 0.55, 0.58],
            });
        }
    }
}

/// A y beside a goal mouth (outside its posts, within the field's width).
fn side_of_goal(rng: &mut ChaCha8Rng) -> f32 {
    let y = rng.random_range(1.2..HALF_WIDTH);
    if rng.random_bool(0.5) { y } else { -y }
}

/// A point on the floor at least `nearest` beyond the carpet and inside the walls.
fn beyond_the_carpet(rng: &mut ChaCha8Rng, nearest: f32, max_x: f32, max_y: f32) -> Vec2 {
    let (cx, cy) = (
        HALF_LENGTH + BORDER + nearest,
        HALF_WIDTH + BORDER + nearest,
    );
    loop {
        let p = Vec2::new(
            rng.random_range(-max_x..max_x),
            rng.random_range(-max_y..max_y),
        );
        if p.x.abs() > cx || p.y.abs() > cy {
            return p;
        }
    }
}

fn draw_sunlight(severity: Severity, rng: &mut ChaCha8Rng) -> Sunlight {
    let elevation = rng
        .random_range(severity.pick([50.0f32, 40.0, 30.0, 25.0, 20.0])..70.0)
        .to_radians();
    let azimuth = rng.random_range(-core::f32::consts::PI..core::f32::consts::PI);
    let towards = Vec3::new(
        elevation.cos() * azimuth.cos(),
        elevation.cos() * azimuth.sin(),
        elevation.sin(),
    );
    let spots = (0..severity.pick([0, 1, 2, 3, 4]))
        .map(|_| BrightSpot {
            centre: Vec2::new(
                rng.random_range(-HALF_LENGTH..HALF_LENGTH),
                rng.random_range(-HALF_WIDTH..HALF_WIDTH),
            ),
            half_axes: Vec2::new(rng.random_range(0.4..1.4), rng.random_range(0.2..0.7)),
            angle: rng.random_range(0.0..core::f32::consts::PI),
            gain: severity.pick([0.25, 0.35, 0.5, 0.7, 0.9]),
        })
        .collect();
    Sunlight {
        towards,
        share: severity.pick([0.15, 0.25, 0.4, 0.5, 0.6]),
        spots,
    }
}

/// A colour with each channel uniform in `range`.
fn random_colour(rng: &mut ChaCha8Rng, range: core::ops::Range<f32>) -> [f32; 3] {
    [0, 1, 2].map(|_| rng.random_range(range.clone()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(text: &str, seed: u64) -> VenueLayout {
        text.parse::<Conditions>()
            .expect("parses")
            .resolve(seed)
            .layout
    }

    #[test]
    fn clean_and_camera_only_conditions_keep_the_paper_arena() {
        assert!(layout("clean", 3).is_standard());
        assert!(layout("noise:5,exposure:5", 3).is_standard());
        assert!(!layout("venue:1", 3).is_standard());
    }

    #[test]
    fn figures_stand_beyond_the_field_lines_and_never_in_a_goal() {
        for seed in 0..200 {
            let drawn = layout("venue:5,robots:5", seed);
            for figure in &drawn.figures {
                let p = figure.position;
                let inside = p.x.abs() < HALF_LENGTH - 0.1 && p.y.abs() < HALF_WIDTH - 0.1;
                assert!(!inside, "{figure:?} stands on the field");
                let in_goal =
                    (HALF_LENGTH - 0.1..HALF_LENGTH + 0.7).contains(&p.x.abs()) && p.y.abs() < 1.0;
                assert!(!in_goal, "{figure:?} stands in a goal mouth");
            }
            let robots = drawn
                .figures
                .iter()
                .filter(|f| f.kind == FigureKind::Robot)
                .count();
            assert_eq!(robots, 8);
        }
    }

    #[test]
    fn harsher_venues_bring_more_people_nearer() {
        let people = |text: &str| {
            layout(text, 11)
                .figures
                .iter()
                .filter(|f| matches!(f.kind, FigureKind::Person { .. }))
                .count()
        };
        assert!(people("venue:5") > people("venue:3"));
        assert!(people("venue:3") > people("venue:1"));
        assert_eq!(layout("unseen-venue:3", 1).style, VenueStyle::Stadium);
    }

    #[test]
    fn a_capsule_blocks_the_lines_through_it_only() {
        let post = Occluder::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.8), 0.05);
        assert!(post.blocks(Vec3::new(0.0, 0.0, 0.5), Vec3::new(2.0, 0.0, 0.05)));
        assert!(!post.blocks(Vec3::new(0.0, 0.0, 0.5), Vec3::new(2.0, 0.3, 0.05)));
        assert!(!post.blocks(Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.9, 0.0, 0.05)));
        let ball = Occluder::new(Vec3::splat(1.0), Vec3::splat(1.0), 0.1);
        assert!(ball.blocks(Vec3::ZERO, Vec3::splat(2.0)));
    }

    #[test]
    fn sunlight_comes_from_above() {
        for seed in 0..50 {
            let sun = layout("light:5", seed).sunlight.expect("light");
            assert!(sun.towards.z > 0.3 && (sun.towards.length() - 1.0).abs() < 1e-5);
        }
    }
}
