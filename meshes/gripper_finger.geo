// softdiff filament finger of the soft Gripper (configs/gripper.yaml), in the spirit of
// Navez et al. 2024, "Design optimization of a soft gripper using self-contacts": a
// closed loop of thin printed filament, driven at one foot by a servomotor, whose inner
// walls touch each other (self-contact) when the finger closes on an object.
// UNITS: millimetres (scenes load it with mesh_scale: 0.001).
//
// Our own construction (no upstream file or outline is copied; the main sizes are the
// published defaults of the TripodFinger design, see meshes/README.md). A planar profile in
// the x-y plane, extruded by Width along +z and meshed in NLayers structured layers:
//  * back leg x in [0, BackThickness], y in [-FootHeight, FingerHeight]: the servo side;
//  * top bar y in [FingerHeight - TopThickness, FingerHeight];
//  * front filament: a strip of thickness FilamentThickness bowed outwards (towards +x, the
//    object) into a circular arc of sagitta BowSagitta, its outer face reaching x =
//    FingerDepth at mid-height; its lower FootHeight (y < 0) is the front foot (clamped);
//  * NBumps knuckles on the inner face of the back leg: half ellipses of half-height
//    BumpHalfHeight reaching to BumpGap from the filament's inner face. When the object
//    pushes the filament in, the filament lands on them (the self-contact);
//  * the servo horn: a bar of height ArmHeight under the feet, joined to the back leg
//    (extended down to it) and reaching to ServoAxisX + ArmOverhang. The servo shaft is the
//    line x = ServoAxisX, y = ServoAxisY (along z): its point is embedded in the profile, so
//    the mesh has a line of nodes on the shaft (NLayers + 1 nodes). Fixing them makes the
//    horn pivot on the shaft; a torque about the shaft (a rotation servo) on the horn's
//    nodes then tilts the back leg towards +x and closes the finger.
// The cavity is open at the bottom between the two feet (y < 0), like the upstream finger;
// the horn's top is ArmGap below the feet, so the horn clears the front foot.
//
// Override any parameter with: gmsh -3 gripper_finger.geo -setnumber NAME VALUE
SetFactory("OpenCASCADE");

DefineConstant[
  FingerHeight      = {100, Name "Finger/FingerHeight (L)"},
  FingerDepth       = {33,  Name "Finger/FingerDepth (l)"},
  BackThickness     = {8,   Name "Finger/BackThickness (e1)"},
  TopThickness      = {5,   Name "Finger/TopThickness (e2)"},
  FilamentThickness = {4,   Name "Finger/FilamentThickness (e3)"},
  Width             = {20,  Name "Finger/Width (w, extrusion along z)"},
  FootHeight        = {6,   Name "Finger/FootHeight"},
  BowSagitta        = {3,   Name "Finger/BowSagitta (> 0)"},
  NBumps            = {4,   Name "Finger/NBumps"},
  BumpHalfHeight    = {6,   Name "Finger/BumpHalfHeight"},
  BumpGap           = {3,   Name "Finger/BumpGap"},
  ServoAxisX        = {30,  Name "Servo/ServoAxisX"},
  ServoAxisY        = {-18, Name "Servo/ServoAxisY"},
  ArmHeight         = {12,  Name "Servo/ArmHeight"},
  ArmOverhang       = {4,   Name "Servo/ArmOverhang (past the shaft)"},
  lc                = {4,   Name "Mesh/lc (in-plane size, thick parts)"},
  lcFilament        = {2,   Name "Mesh/lcFilament (in-plane size near the filament)"},
  NLayers           = {4,   Name "Mesh/NLayers (element layers across Width)"}
];
L = FingerHeight; l = FingerDepth; e1 = BackThickness; e2 = TopThickness; e3 = FilamentThickness;
If (BowSagitta <= 0)
  Error("gripper_finger.geo: BowSagitta must be > 0");
EndIf
armTop = ServoAxisY + ArmHeight / 2;
armBot = ServoAxisY - ArmHeight / 2;
If (armTop > -FootHeight - 1)
  Error("gripper_finger.geo: the horn (top y = %g) must stay 1 mm below the feet (y = %g)", armTop, -FootHeight);
EndIf

// the filament's centreline: the arc through (l - e3/2 - s, 0), (l - e3/2, ym), (l - e3/2 - s, 2 ym)
s = BowSagitta;
ym = (L - e2) / 2;                         // mid-height of the cavity
rho = (ym * ym + s * s) / (2 * s);         // radius of the centreline
cx = l - e3 / 2 - rho;
cy = ym;
big = 2 * (rho + e3);

// solid bounded on the right by the filament's outer face
r0 = news; Rectangle(r0) = {0, -FootHeight, 0, l + 5, L + FootHeight};
d0 = news; Disk(d0) = {cx, cy, 0, rho + e3 / 2};
frame[] = BooleanIntersection{ Surface{r0}; Delete; }{ Surface{d0}; Delete; };
// the cavity, bounded on the right by the filament's inner face, open at the bottom
r1 = news; Rectangle(r1) = {e1, -FootHeight - 1, 0, l + 5 - e1, L - e2 + FootHeight + 1};
d1 = news; Disk(d1) = {cx, cy, 0, rho - e3 / 2};
cav[] = BooleanIntersection{ Surface{r1}; Delete; }{ Surface{d1}; Delete; };
loop[] = BooleanDifference{ Surface{frame[]}; Delete; }{ Surface{cav[]}; Delete; };

// knuckles on the back leg, each reaching to BumpGap from the filament's inner face
parts[] = {};
For k In {0 : NBumps - 1}
  yk = (k + 0.5) * (L - e2) / NBumps;
  xin = cx + Sqrt((rho - e3 / 2) ^ 2 - (yk - cy) ^ 2);   // inner face of the filament at yk
  ax = xin - BumpGap - e1;
  If (ax < BumpHalfHeight)
    Error("gripper_finger.geo: knuckle %g: reach %g below its half-height (OpenCASCADE ellipse)", k, ax);
  EndIf
  db = news; Disk(db) = {e1, yk, 0, ax, BumpHalfHeight};
  rb = news; Rectangle(rb) = {e1 - 1, yk - BumpHalfHeight - 1, 0, ax + 2, 2 * BumpHalfHeight + 2};
  bk[] = BooleanIntersection{ Surface{db}; Delete; }{ Surface{rb}; Delete; };
  parts[] += {bk[]};
EndFor
If ((NBumps > 0) && ((L - e2) / NBumps < 2 * BumpHalfHeight + 2))
  Error("gripper_finger.geo: the knuckles overlap (spacing %g)", (L - e2) / NBumps);
EndIf

// servo horn and the back leg's extension down to it
ra = news; Rectangle(ra) = {0, armBot, 0, ServoAxisX + ArmOverhang, ArmHeight};
re = news; Rectangle(re) = {0, armBot, 0, e1, -FootHeight - armBot + 1};
parts[] += {ra, re};
prof[] = BooleanUnion{ Surface{loop[]}; Delete; }{ Surface{parts[]}; Delete; };
If (#prof[] != 1)
  Error("gripper_finger.geo: the profile has %g pieces", #prof[]);
EndIf

// the servo shaft: a mesh node of the profile, hence a line of nodes after extrusion
ps = newp; Point(ps) = {ServoAxisX, ServoAxisY, 0};
Point{ps} In Surface{prof[0]};

// mesh sizes: lcFilament in a band around the filament (and the knuckle tips), lc elsewhere
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeExtendFromBoundary = 0;
Mesh.MeshSizeFromCurvature = 0;
Field[1] = Box;
Field[1].VIn = lcFilament;
Field[1].VOut = lc;
Field[1].XMin = l - e3 - s - BumpGap - 1.5; Field[1].XMax = l + 1;
Field[1].YMin = -FootHeight - 1;            Field[1].YMax = L + 1;
Field[1].ZMin = -1;                         Field[1].ZMax = 1;
Field[1].Thickness = 3;
Background Field = 1;
Mesh.Algorithm = 6;          // Frontal-Delaunay for the profile
Mesh.Optimize = 1;
Mesh.ElementOrder = 1;

ex[] = Extrude {0, 0, Width} { Surface{prof[0]}; Layers{NLayers}; };

eps = 1e-3;
ffoot[] = Surface In BoundingBox {e1 + eps, -FootHeight - eps, -eps, l + 1, -FootHeight + eps, Width + eps};
Physical Surface("front_foot") = {ffoot[]};
Physical Volume("finger") = {ex[1]};
