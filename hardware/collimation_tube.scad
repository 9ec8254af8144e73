// Collimation tube: carries the paper diffuser 8 mm below the LED, a source aperture under it, and knife-edge
// baffles that keep light reflected from the tube wall off the sensor. Print it in matte black filament (or
// paint the bore matte black): a shiny bore adds oblique light, which is exactly what the calibration must not
// see. Printed upright, bottom flange on the bed; the top flange's underside is a 45 degree cone so it needs no
// supports. Render on its own: openscad -o collimation_tube.stl collimation_tube.scad

include <parameters.scad>

// Radius that every ray from the source aperture to the sensor disc stays inside, at world height z.
function beam_envelope(z, paper_z_world) =
    sensor_clear_radius + (source_aperture / 2 - sensor_clear_radius) * z / paper_z_world;

// Tube in its own frame: z = 0 on the bottom face (which sits on the seat), z = length at the LED holder.
module collimation_tube(length = tube_length) {
    r_bore = tube_bore / 2;
    r_out = tube_outer_diameter / 2;
    r_flange = flange_diameter / 2;
    r_stop = source_aperture / 2;
    paper_z = length - led_height - diffuser_distance;
    stop_bottom = paper_z - baffle_edge - (r_bore - r_stop);
    baffles = [for (z = [baffle_pitch : baffle_pitch : stop_bottom - 3])
        let (r = beam_envelope(seat_top_z + z, seat_top_z + paper_z) + baffle_margin)
        if (r < r_bore - 0.5) [z, r]];
    // Descending the bore: a knife edge (flat top facing the source, 45 degree underside) per baffle.
    function knife(z, r) = [[r_bore, z], [r, z], [r, z - baffle_edge], [r_bore, z - baffle_edge - (r_bore - r)]];
    inner = [for (k = [len(baffles) - 1 : -1 : 0]) each knife(baffles[k][0], baffles[k][1])];
    outer = [
        [r_bore, 0], [r_flange, 0], [r_flange, flange_thickness], [r_out, flange_thickness],
        [r_out, length - flange_thickness - (r_flange - r_out)], [r_flange, length - flange_thickness],
        [r_flange, length], [r_bore, length],
    ];
    assert(stop_bottom > baffle_pitch, "tube_length is too short for the diffuser and one baffle");
    difference() {
        // The stop is drawn a little higher than the paper and trimmed to it by the slot below: a cut right
        // through, rather than two faces that only nearly meet.
        rotate_extrude() polygon(concat(outer, knife(paper_z + 0.1, r_stop), inner));
        // Slot for the paper diffuser, open to the front; the paper lies on the source-aperture stop.
        translate([-(r_bore + 0.5), -(r_flange + 1), paper_z])
            cube([tube_bore + 1, r_flange + 1 + r_bore + 0.8, diffuser_slot_height]);
        for (sy = [-1, 1]) {
            // Bottom flange: screws pass through into the seat.
            translate([0, sy * flange_screw_spacing / 2, -eps])
                cylinder(d = m3_clearance, h = flange_thickness + 2 * eps);
            // Top flange: the LED holder's screws cut their thread here.
            translate([0, sy * flange_screw_spacing / 2, length - flange_thickness - 2])
                cylinder(d = m3_pilot, h = flange_thickness + 2 + eps);
        }
    }
}

if (is_undef(in_assembly)) collimation_tube();
