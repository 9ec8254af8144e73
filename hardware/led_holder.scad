// LED holder: a cap on the tube's top flange. The NeoPixel board sits LED-down in a pocket in its underside,
// bearing on small tabs so that its face is flush with the tube top: the LED's emitting face is then led_height
// below the tube top and diffuser_distance above the paper. Behind the board there is room for the solder
// joints (turn the board so the tabs fall between them); the wires leave through a hole in the roof.
// Printed roof-down (the STL is already turned over), so the pocket opens upwards and nothing overhangs.
// Render on its own: openscad -o led_holder.stl led_holder.scad

include <parameters.scad>

module led_board_outline(inset = 0) {
    size = led_board_size + 2 * fit_clearance - 2 * inset;
    if (led_board_shape == "round") circle(d = size);
    else if (led_board_shape == "square") square(size, center = true);
    else assert(false, str("led_board_shape must be \"round\" or \"square\", not ", led_board_shape));
}

// Three tabs on a round board's rim, or one in each corner of a square board: 1 mm wide ledges to bear on.
module led_board_tabs() {
    round = led_board_shape == "round";
    edge = (led_board_size / 2 + fit_clearance) * (round ? 1 : sqrt(2));
    for (a = round ? [90, 210, 330] : [45, 135, 225, 315]) rotate(a) translate([edge - 1, -0.75]) square([2, 1.5]);
}

// Cap in its own frame: z = 0 on the underside (on the tube's top face), z = cap_thickness on top.
module led_holder() {
    pocket = led_board_thickness + led_solder_relief;
    assert(pocket + 1.5 <= cap_thickness, "cap_thickness leaves no roof over the LED board");
    difference() {
        cylinder(d = flange_diameter, h = cap_thickness);
        // The board's outline, and behind it room for the solder joints.
        translate([0, 0, -eps]) linear_extrude(pocket + eps) led_board_outline();
        translate([0, 0, -eps]) cylinder(d = led_wire_hole, h = cap_thickness + 2 * eps);
        for (sy = [-1, 1]) translate([0, sy * flange_screw_spacing / 2, -eps]) {
            cylinder(d = m3_clearance, h = cap_thickness + 2 * eps);
        }
    }
    // The tabs the board bears on (they reach into the wall, so they join it).
    translate([0, 0, led_board_thickness]) linear_extrude(led_solder_relief + eps) led_board_tabs();
}

if (is_undef(in_assembly)) translate([0, 0, cap_thickness]) rotate([180, 0, 0]) led_holder();
