// The whole jig, every part in place, with the camera tilted by `tilt` degrees about the x axis (through the
// sensor): openscad -o assembly.stl -D tilt=20 assembly.scad. For looking at, not for printing; the bought
// parts (camera board, LED board, paper diffuser) are drawn too unless show_vitamins = false.

in_assembly = true;  // the part files below define their modules without placing a part of their own
include <parameters.scad>
include <rotation_seat.scad>
include <camera_holder.scad>
include <collimation_tube.scad>
include <led_holder.scad>

tilt = 0;
show_vitamins = true;

assert(abs(tilt) <= tilt_max, str("tilt must be within +-tilt_max (", tilt_max, " degrees), not ", tilt));

tube_top_z = seat_top_z + tube_length;

color("dimgray") rotation_seat();
rotate([tilt, 0, 0]) {
    color("slategray") camera_holder();
    if (show_vitamins) color("green") camera_board();
}
color("black") translate([0, 0, seat_top_z]) collimation_tube();
color("dimgray") translate([0, 0, tube_top_z]) led_holder();

if (show_vitamins) {
    // NeoPixel board LED-down in the holder's pocket, its LED reaching into the tube.
    color("white") translate([0, 0, tube_top_z])
        linear_extrude(led_board_thickness) led_board_outline(inset = fit_clearance);
    color("yellow") translate([-led_package / 2, -led_package / 2, led_face_z])
        cube([led_package, led_package, led_height + eps]);
    // Paper diffuser strip on the slot floor, with a tab left outside to pull it by.
    color("ivory") translate([-(tube_bore + 0.5) / 2, -(flange_diameter / 2 + 4), diffuser_z])
        cube([tube_bore + 0.5, flange_diameter / 2 + 4 + tube_bore / 2 + 0.5, 0.1]);
}
