// Rotation seat: the fixed half of the rotation stage and the jig's base. A cylindrical seat holds the camera
// holder's drum, so the drum turns about an axis through the sensor; the collimation tube stands on top, located
// by a ring inside its bore and held by two M3 screws. The front (-y) boss takes the M3 clamp screw; the pointer
// over the dial reads the angle marks. The bore's top is a flat-topped teardrop so the seat prints on its base
// without supports; the drum bears on the round lower part.
// Render on its own: openscad -o rotation_seat.stl rotation_seat.scad

include <parameters.scad>

flange_screw_depth = 8;
clamp_boss_width = 9;

// Cross-section of the bore in the plane of x = 0, as it lies before rotate([0, 90, 0]) (2D +x is world -z).
module seat_bore_profile() {
    r = seat_bore_radius;
    intersection() {
        rotate(90) hull() {
            circle(r = r);
            rotate(45) square(r);
        }
        translate([-(r + 1.5), -r - 1]) square([2 * r + 2.5, 2 * r + 2]);
    }
}

// Seat in the world frame (sensor at the origin).
module rotation_seat() {
    half_length = seat_half_length;
    half_width = seat_bore_radius + seat_side_wall;
    difference() {
        union() {
            translate([-half_length, -half_width, seat_bottom_z])
                cube([2 * half_length, 2 * half_width, seat_top_z - seat_bottom_z]);
            translate([-half_length, -seat_base_width / 2, seat_bottom_z])
                cube([2 * half_length, seat_base_width, seat_base_thickness]);
            // Clamp-screw boss, a buttress rising from the base plate.
            translate([groove_x - clamp_boss_width / 2, -half_width - seat_boss_length, seat_bottom_z])
                cube([clamp_boss_width, seat_boss_length + eps, clamp_boss_width / 2 - seat_bottom_z]);
            // Locates the tube: a ring that fits inside its bore.
            translate([0, 0, seat_top_z - eps]) cylinder(r = tube_bore / 2 - clearance, h = centring_boss_height + eps);
            // Pointer over the dial; its underside slopes at about 48 degrees, so it prints unsupported.
            hull() {
                translate([dial_x0, -2.5, seat_top_z - 0.5]) cube([-dial_x0 - half_length + eps, 5, 0.5]);
                translate([dial_x0, -0.1, dial_radius + 0.6]) cube([-dial_x0 - half_length + eps, 0.2, 0.1]);
            }
        }
        translate([-half_length - 1, 0, 0]) rotate([0, 90, 0])
            linear_extrude(2 * half_length + 2) seat_bore_profile();
        cylinder(r = seat_light_radius, h = seat_top_z + centring_boss_height + 1);
        for (sy = [-1, 1]) translate([0, sy * flange_screw_spacing / 2, seat_top_z - flange_screw_depth])
            cylinder(d = m3_pilot, h = flange_screw_depth + eps);
        translate([groove_x, -half_width - seat_boss_length - 1, 0]) rotate([-90, 0, 0])
            cylinder(d = m3_pilot, h = seat_boss_length + seat_side_wall + 2);
        for (sx = [-1, 1], sy = [-1, 1])
            translate([sx * (half_length - 6), sy * (seat_base_width / 2 - 6), seat_bottom_z - eps])
                cylinder(d = bench_hole, h = seat_base_thickness + 2 * eps);
    }
}

if (is_undef(in_assembly)) translate([0, 0, -seat_bottom_z]) rotation_seat();
