// Camera holder: the rotating half of the rotation stage. A drum whose axis (x) passes through the sensor
// surface; the lens-less camera board is screwed face-up onto four bosses between the drum's cheeks, so at zero
// tilt the sensor is square to the tube axis. The drum turns in rotation_seat.scad; the dial outside the seat
// carries an angle mark every tick_step degrees (every third one longer, the 0 mark longest), read against the
// seat's pointer. The V groove takes the tip of the clamp screw: loose, it keeps the drum from sliding out; tight, it
// locks the angle. Printed standing on the dial (the STL is already turned so).
// Render on its own: openscad -o camera_holder.stl camera_holder.scad

include <parameters.scad>

boss_diameter = 4.5;
m2_screw_depth = 6;

// A shape along +x, from x0 to x1, of the given radius.
module x_cylinder(r, x0, x1) {
    translate([x0, 0, 0]) rotate([0, 90, 0]) cylinder(r = r, h = x1 - x0);
}

// Space behind the board for its components, keeping a boss under each mounting hole (merged into the cheek).
module back_pocket() {
    w = drum_pocket_half_width;
    z0 = board_back_z - cam_back_clearance;
    difference() {
        translate([drum_pocket_x0, -w, z0]) cube([drum_x1 - drum_pocket_x0 + 1, 2 * w, cam_back_clearance + eps]);
        for (hole = cam_holes) hull() {
            translate([hole[0], hole[1], z0 - eps]) cylinder(d = boss_diameter, h = cam_back_clearance + 3 * eps);
            translate([hole[0] - boss_diameter / 2, sign(hole[1]) * w - 0.5, z0 - eps])
                cube([boss_diameter, 1, cam_back_clearance + 3 * eps]);
        }
    }
}

// Camera holder at zero tilt in the world frame (sensor at the origin).
module camera_holder() {
    w = drum_pocket_half_width;
    marks = round(tilt_max / tick_step);
    difference() {
        union() {
            x_cylinder(drum_radius, dial_x1 - eps, drum_x1);
            x_cylinder(dial_radius, dial_x0, dial_x1);
        }
        // Open above the board: the camera, its flex and the light are all on this side.
        translate([drum_pocket_x0, -w, board_back_z])
            cube([drum_x1 - drum_pocket_x0 + 1, 2 * w, drum_radius - board_back_z + 1]);
        back_pocket();
        for (hole = cam_holes) translate([hole[0], hole[1], board_back_z - m2_screw_depth])
            cylinder(d = m2_pilot, h = m2_screw_depth + eps);
        // Clamp-screw groove, centred on the front (-y) where the screw is, long enough for +-tilt_max.
        translate([groove_x, 0, 0]) rotate([-90, 0, 0]) rotate([0, 90, 0]) rotate([0, 0, -groove_half_angle])
            rotate_extrude(angle = 2 * groove_half_angle)
                polygon([[drum_radius - groove_depth, 0], [drum_radius + 1, -groove_depth - 1],
                         [drum_radius + 1, groove_depth + 1]]);
        // Angle marks on the dial's rim, starting from its outer face.
        for (k = [-marks : marks]) {
            length = k == 0 ? dial_thickness + 1 : (k % 3 == 0 ? 3 : 2);
            rotate([k * tick_step, 0, 0]) translate([dial_x0 - eps, -tick_width / 2, dial_radius - tick_depth])
                cube([length + eps, tick_width, tick_depth + 1]);
        }
    }
}

// The parts that are bought, not printed: the camera board with its lens-less camera housing.
module camera_board() {
    translate([cam_far_edge_x, -cam_board[0] / 2 - cam_sensor_offset, board_back_z]) difference() {
        cube([cam_board[1], cam_board[0], cam_board_thickness]);
        for (hole = cam_holes) translate([hole[0] - cam_far_edge_x, hole[1] + cam_board[0] / 2 + cam_sensor_offset, -1])
            cylinder(d = cam_hole_diameter, h = cam_board_thickness + 2);
    }
    translate([-cam_housing[0] / 2, -cam_housing[1] / 2, board_front_z - eps]) cube(cam_housing + [0, 0, eps]);
}

if (is_undef(in_assembly)) translate([0, 0, -dial_x0]) rotate([0, -90, 0]) camera_holder();
