// Shared dimensions of the picamcal calibration jig (all lengths in mm, angles in degrees).
//
// Every part file includes this file, so a value changed here, or on the command line with
// `openscad -D name=value`, changes every part that depends on it.
//
// World frame, used by assembly.scad and by the parts before they are turned to their print orientation:
//   origin  the centre of the image sensor, on the sensor surface;
//   +z      the tube axis, pointing from the sensor towards the LED (light travels along -z);
//   +x      the tilt (rotation) axis, pointing towards the end where the ribbon cable leaves;
//   -y      the front of the jig: the clamp screw and the diffuser slot face this way.
// A positive `tilt` is a right-handed rotation of the camera about +x: the sensor turns to face the front.

// ---------------------------------------------------------------------------------------------------------
// FDM printing
// ---------------------------------------------------------------------------------------------------------
clearance = 0.25;      // radial play of the sliding fit between the drum and its seat
fit_clearance = 0.2;   // play around bought parts (camera board, LED board) in their pockets
$fa = 4;               // default smoothness; tests override with -D '$fn=32' to render quickly
$fs = 0.4;
eps = 0.01;            // overlap that keeps boolean operations free of coincident faces

// ---------------------------------------------------------------------------------------------------------
// Screws: they cut their own thread in printed pilot holes (PLA or PETG), as OpenFlexure parts do
// ---------------------------------------------------------------------------------------------------------
m2_pilot = 1.8;        // M2 self-tapping pilot
m3_pilot = 2.6;        // M3 self-tapping pilot
m3_clearance = 3.4;    // M3 passes freely
m3_head = 5.7;         // M3 socket or pan head diameter, plus a little

// ---------------------------------------------------------------------------------------------------------
// Raspberry Pi Camera Module v2 (Sony IMX219), from the published mechanical drawing as we remember it.
// The board outline, hole size and hole pattern are well established; the sensor position and heights are
// less certain, so they are parameters to measure on your own board with calipers.
// ---------------------------------------------------------------------------------------------------------
cam_board = [25, 24];                // [across, along]: the 25 mm side carries the 21 mm hole spacing
                                     // (the drawing says 23.86 mm for the 24 mm side)
cam_board_thickness = 1.0;
cam_hole_diameter = 2.2;             // four holes, for M2 screws
cam_hole_spacing = [21, 12.5];       // centre to centre, [across, along]; holes 2 mm from the side edges
cam_sensor_from_connector_edge = 9.6;  // along: ribbon-connector edge to the sensor centre. The sensor sits on
                                       // the line of the two holes nearer the connector (OpenFlexure's v2
                                       // mount uses 9.6; 24 - 2 - 12.5 = 9.5). Uncertain by about 0.3 mm.
cam_sensor_offset = 0;               // across: sensor centre from the board's centre line (nominally 0;
                                     // the die inside its housing may sit a few tenths off; measure)
cam_sensor_height = 1.5;             // sensor surface above the board's front face (module on foam tape;
                                     // uncertain, 1.0-2.0). It sets how close the tilt axis passes to the
                                     // sensor surface; an error here only moves the sensor by
                                     // error * sin(tilt) in the uniform beam, which does not matter.
cam_housing = [8.5, 8.5, 4.0];       // lens-less camera housing on the front [x, y, height]; height uncertain
cam_back_clearance = 3.0;            // components on the back: ribbon socket 2.7 mm, others up to 2 mm
cam_ribbon_width = 16;               // 15-way, 1 mm pitch flat flex cable
sensor_clear_radius = 3.0;           // IMX219 active area 3.68 x 2.76 mm (4.6 mm diagonal) plus margin for
                                     // the uncertain sensor position: the beam must cover this disc

// ---------------------------------------------------------------------------------------------------------
// NeoPixel (WS2812 / WS2812B): one RGB LED on a small breakout board, LED facing the diffuser.
// Common boards: 10 mm round WS2812B "heat sink" boards (the default), 8 mm round mini boards
// (led_board_size = 8), Adafruit Flora v2 (round, 12.7), square 5050 breakouts (led_board_shape = "square").
// ---------------------------------------------------------------------------------------------------------
led_board_shape = "round";           // "round" or "square"
led_board_size = 10;                 // diameter (round) or side (square)
led_board_thickness = 1.6;
led_height = 1.6;                    // 5050 package height above its board: the emitting face
led_package = 5.0;                   // 5050 package side
led_solder_relief = 1.5;             // room behind the board for solder joints and wire ends
led_wire_hole = 4;                   // three wires (5 V, GND, DIN) leave through the holder's roof

// ---------------------------------------------------------------------------------------------------------
// Collimation tube: LED -> paper diffuser -> source aperture -> baffled tube -> sensor
// ---------------------------------------------------------------------------------------------------------
tube_length = 60;                    // printed length of the tube; the sensor sits a further seat_top_z below
tube_bore = 12;
tube_wall = 2;
diffuser_distance = 8;               // paper: white paper 8 mm from the LED, which attenuates and spreads it
diffuser_slot_height = 0.8;          // takes one or two sheets of 80 g/m2 paper (0.1 mm each)
source_aperture = 6;                 // stop just under the diffuser: the size of the source seen by the sensor
baffle_pitch = 10;                   // knife-edge baffles against light reflected from the tube wall
baffle_margin = 0.75;                // baffle apertures clear every ray from the source to the sensor by this
baffle_edge = 0.6;                   // thickness of a baffle at its knife edge
flange_diameter = 30;
flange_thickness = 5;
flange_screw_spacing = 23;           // two M3 screws on the y axis in each flange
cap_thickness = 5;                   // LED holder

// ---------------------------------------------------------------------------------------------------------
// Rotation stage: the camera holder is a drum whose axis passes through the sensor; it turns in a
// cylindrical seat and is locked by a clamp screw whose tip runs in a groove.
// ---------------------------------------------------------------------------------------------------------
tilt_max = 30;                       // the angle marks and the clamp groove cover -tilt_max..+tilt_max
tick_step = 5;                       // an angle mark every 5 degrees; every third one longer, 0 the longest
drum_radius = 18.5;
drum_end_wall = 3;                   // full-circle wall at the dial end, part of the bearing
drum_cable_end = 5;                  // drum length beyond the board's connector edge (clamp groove)
dial_radius = drum_radius + 2.5;     // dial outside the seat; also stops the drum sliding in too far
dial_thickness = 4;
dial_gap = 0.3;                      // between the dial and the seat's end face
tick_width = 0.8;
tick_depth = 0.8;
groove_depth = 1.5;                  // V groove (90 degrees) for the clamp screw's tip
seat_top_wall = 6;
seat_side_wall = 3;
seat_bottom_wall = 3;
seat_boss_length = 4;                // clamp screw boss on the front wall
seat_base_width = 70;                // base plate across y, for stability
seat_base_thickness = 4;
bench_hole = 4.5;                    // optional M4 holes to fix the base to a board
centring_boss_height = 2;            // ring on the seat that locates the tube's bore

// ---------------------------------------------------------------------------------------------------------
// Derived positions (world frame). Change the values above, not these.
// ---------------------------------------------------------------------------------------------------------
tube_outer_diameter = tube_bore + 2 * tube_wall;
seat_bore_radius = drum_radius + clearance;
seat_top_z = seat_bore_radius + seat_top_wall;        // tube bottom face
seat_bottom_z = -(seat_bore_radius + seat_bottom_wall);
seat_light_radius = sensor_clear_radius + 1.5;
led_face_z = seat_top_z + tube_length - led_height;   // emitting face of the LED
diffuser_z = led_face_z - diffuser_distance;          // the paper lies on the slot floor at this height
board_front_z = -cam_sensor_height;
board_back_z = board_front_z - cam_board_thickness;
beam_half_angle = atan((source_aperture / 2 + sensor_clear_radius) / diffuser_z);

// Along x (the tilt axis), from the dial end to the cable end
cam_connector_edge_x = cam_sensor_from_connector_edge;
cam_far_edge_x = cam_sensor_from_connector_edge - cam_board[1];
drum_pocket_x0 = cam_far_edge_x - 2 * fit_clearance;
seat_half_length = drum_end_wall - drum_pocket_x0;   // the seat is symmetric about the tube axis
dial_x1 = -seat_half_length - dial_gap;
dial_x0 = dial_x1 - dial_thickness;
drum_x1 = cam_connector_edge_x + drum_cable_end;
groove_x = (cam_connector_edge_x + drum_x1) / 2;
drum_pocket_half_width = cam_board[0] / 2 + fit_clearance;
cheek_top_z = sqrt(drum_radius * drum_radius - drum_pocket_half_width * drum_pocket_half_width);
groove_half_angle = tilt_max + 5;
// Camera hole centres in the world frame at zero tilt
cam_holes = [for (sx = [-1, 1], along = [0, cam_hole_spacing[1]])
    [-along, sx * cam_hole_spacing[0] / 2 - cam_sensor_offset]];

// ---------------------------------------------------------------------------------------------------------
// Checks that the numbers above still describe a jig that works
// ---------------------------------------------------------------------------------------------------------
assert(drum_x1 < seat_half_length, "the drum must end inside its seat");
assert(dial_radius < seat_bore_radius + seat_bottom_wall, "the dial must clear the bench");
assert(sensor_clear_radius + cheek_top_z * tan(tilt_max + beam_half_angle) < drum_pocket_half_width,
       "at tilt_max the drum's cheeks would cut into the beam: lower tilt_max or widen the drum");
assert(drum_radius * sin(groove_half_angle) + groove_depth < cheek_top_z,
       "the clamp groove runs off the drum's cheeks: lower tilt_max or enlarge drum_radius");
assert(norm([drum_pocket_half_width, board_back_z - cam_back_clearance]) < drum_radius - 1.5,
       "the camera board does not fit inside the drum");
assert(flange_screw_spacing / 2 - m3_head / 2 > tube_outer_diameter / 2,
       "flange screw heads would hit the tube wall");
assert(source_aperture < tube_bore, "the source aperture must be smaller than the bore");
