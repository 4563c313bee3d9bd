//! The SPL field in the field frame (DESIGN.md): origin at the centre spot, x along the long
//! axis toward the opponent goal, y to the left, z up; metres.

use glam::Vec2;

/// Dimensions of an SPL field, its goals and its ball.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldGeometry {
    /// Length inside the lines, along x.
    pub length: f32,
    /// Width inside the lines, along y.
    pub width: f32,
    /// Carpet beyond the outer lines.
    pub border: f32,
    pub line_width: f32,
    pub centre_circle_diameter: f32,
    /// Penalty area: depth from the goal line (x) and width (y), outer edges of its lines.
    pub penalty_area: [f32; 2],
    /// Goal area: depth from the goal line and width, as the penalty area.
    pub goal_area: [f32; 2],
    /// Distance between the inner faces of the posts.
    pub goal_inner_width: f32,
    pub goal_post_diameter: f32,
    pub goal_height: f32,
    pub ball_diameter: f32,
}

impl FieldGeometry {
    /// The RoboCup SPL field as DESIGN.md gives it.
    pub const SPL: Self = Self {
        length: 9.0,
        width: 6.0,
        border: 0.7,
        line_width: 0.05,
        centre_circle_diameter: 1.5,
        penalty_area: [1.65, 4.0],
        goal_area: [0.6, 2.2],
        goal_inner_width: 1.5,
        goal_post_diameter: 0.1,
        goal_height: 0.8,
        ball_diameter: 0.1,
    };

    /// x of the goal line of the goal at `side` (+1 toward +x, -1 toward -x).
    pub fn goal_line_x(&self, side: f32) -> f32 {
        side.signum() * self.length / 2.0
    }

    /// Centres of the two posts of the goal at `side`, as (x, y), left post (larger y) first.
    pub fn goal_post_centres(&self, side: f32) -> [(f32, f32); 2] {
        let x = self.goal_line_x(side);
        let y = (self.goal_inner_width + self.goal_post_diameter) / 2.0;
        [(x, y), (x, -y)]
    }

    /// The penalty area, then the goal area, each as (depth from the goal line, half width).
    pub fn areas(&self) -> [(f32, f32); 2] {
        [self.penalty_area, self.goal_area].map(|[depth, width]| (depth, width / 2.0))
    }

    /// The painted lines as polylines through their middles, for pictures of the field: the
    /// boundary, the centre line, the centre circle (`circle_segments` straight pieces), and
    /// each side's penalty and goal areas.
    pub fn line_polylines(&self, circle_segments: usize) -> Vec<Vec<Vec2>> {
        let (hl, hw) = (self.length / 2.0, self.width / 2.0);
        let radius = self.centre_circle_diameter / 2.0;
        let segments = circle_segments.max(3);
        let mut lines = vec![
            vec![
                Vec2::new(-hl, -hw),
                Vec2::new(hl, -hw),
                Vec2::new(hl, hw),
                Vec2::new(-hl, hw),
                Vec2::new(-hl, -hw),
            ],
            vec![Vec2::new(0.0, -hw), Vec2::new(0.0, hw)],
            (0..=segments)
                .map(|i| {
                    Vec2::from_angle(i as f32 / segments as f32 * std::f32::consts::TAU) * radius
                })
                .collect(),
        ];
        for side in [-1.0f32, 1.0] {
            for (depth, half_width) in self.areas() {
                let (goal_line, front) = (side * hl, side * (hl - depth));
                lines.push(vec![
                    Vec2::new(goal_line, -half_width),
                    Vec2::new(front, -half_width),
                    Vec2::new(front, half_width),
                    Vec2::new(goal_line, half_width),
                ]);
            }
        }
        lines
    }

    /// Whether a ball centred at (x, y) has wholly crossed the goal line between the posts of
    /// the goal at `side`: the rule for a goal.
    pub fn is_goal(&self, side: f32, x: f32, y: f32) -> bool {
        let radius = self.ball_diameter / 2.0;
        let beyond_line = side.signum() * x > self.length / 2.0 + radius;
        beyond_line && y.abs() < self.goal_inner_width / 2.0
    }

    /// Whether a ball centred at (x, y) is wholly outside the field lines.
    pub fn is_out(&self, x: f32, y: f32) -> bool {
        let radius = self.ball_diameter / 2.0;
        x.abs() > self.length / 2.0 + radius || y.abs() > self.width / 2.0 + radius
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn posts_stand_outside_the_goal_mouth() {
        let field = FieldGeometry::SPL;
        let [left, right] = field.goal_post_centres(1.0);
        assert_eq!(left, (4.5, 0.8));
        assert_eq!(right, (4.5, -0.8));
        assert_eq!(field.goal_post_centres(-1.0)[0].0, -4.5);
    }

    #[test]
    fn a_goal_needs_the_whole_ball_over_the_line_between_the_posts() {
        let field = FieldGeometry::SPL;
        assert!(!field.is_goal(1.0, 4.5, 0.0), "on the line");
        assert!(!field.is_goal(1.0, 4.54, 0.0), "not wholly over");
        assert!(field.is_goal(1.0, 4.56, 0.0));
        assert!(!field.is_goal(1.0, 4.56, 0.8), "beside the goal");
        assert!(!field.is_goal(-1.0, 4.56, 0.0), "the other goal");
        assert!(field.is_goal(-1.0, -4.6, 0.3));
    }

    #[test]
    fn out_means_wholly_outside_the_lines() {
        let field = FieldGeometry::SPL;
        assert!(!field.is_out(0.0, 3.0));
        assert!(field.is_out(0.0, 3.06));
        assert!(field.is_out(-4.6, 1.0));
    }
}
