// softdiff Finger of the pianist: the 3-segment, 2-cable finger of CondensedFEMModel
// (Models/Finger, after Navarro et al. 2020), rebuilt from its published constants.
// UNITS: millimetres (like the CondensedFEMModel scene; scenes load it with mesh_scale: 0.001).
//
// Axis along -z: base (clamped) face at z = 0, tip face at z = -NSegments*SegmentLength.
// y is the height (0 = flat underside), x the thickness (symmetric about x = 0).
//  * Segments: a prism of section Thickness (x) by Height (y) and length SegmentLength (z) each.
//    Above y = JointHeight, every segment end that meets a joint, and the tip, is cut by a
//    plane inclined by JointSlopeAngle from the y axis: the section in the y-z plane drops
//    from y = Height to y = JointHeight over (Height-JointHeight)*tan(JointSlopeAngle) in z,
//    so neighbouring segments form a V-shaped gap whose bottom is at y = JointHeight on the
//    joint plane z = -j*SegmentLength. The cable points (CableHeight = 2(Height-JointHeight)/3,
//    JointStandoff = CableHeight*tan(JointSlopeAngle)) lie exactly on these planes.
//  * Joints (accordion, NBellowSteps = 1): half of a double cone about the z axis (y >= 0),
//    radius OuterRadius on the joint plane, shrinking to Thickness/2 at +/- StepHeight.
//  * Fixation: a plate of thickness FixationWidth (z in [-FixationWidth, 0]) that overhangs
//    the section by FixationWidth in +x, -x and +y.
// The four internal sensing cavities of the original are not modelled (solid finger, like
// CondensedFEMModel's FingerFine meshes, which fill them).
//
// Override any parameter with: gmsh -3 finger.geo -setnumber NAME VALUE
SetFactory("OpenCASCADE");

DefineConstant[
  SegmentLength   = {40,   Name "Finger/SegmentLength (CondensedFEMModel: Length)"},
  NSegments       = {3,    Name "Finger/NSegments"},
  Height          = {20,   Name "Finger/Height"},
  JointHeight     = {6,    Name "Finger/JointHeight"},
  Thickness       = {17.5, Name "Finger/Thickness"},
  JointSlopeAngle = {45,   Name "Finger/JointSlopeAngle (deg)"},
  FixationWidth   = {3,    Name "Finger/FixationWidth"},
  BellowDepth     = {6,    Name "Finger/BellowDepth (OuterRadius - Thickness/2)"},
  StepHeight      = {4,    Name "Finger/StepHeight"},
  lc              = {3,    Name "Mesh/lc (target element size)"}
];
OuterRadius = Thickness / 2 + BellowDepth;                 // 14.75 with the defaults
standoff = (Height - JointHeight) * Tan(JointSlopeAngle * Pi / 180);
If (2 * standoff > SegmentLength)
  Error("finger.geo: the chamfers of a segment overlap (2*standoff > SegmentLength)");
EndIf
tipZ = -NSegments * SegmentLength;

// ---- side profile in the plane x = -Thickness/2 (coordinates (x, y, z)), extruded along +x
p0 = newp;
np = 0;
Point(p0 + np) = {-Thickness / 2, 0, 0};          np += 1;
Point(p0 + np) = {-Thickness / 2, Height, 0};     np += 1;
For j In {1 : NSegments}
  zj = -j * SegmentLength;                               // joint plane (or the tip, j = NSegments)
  Point(p0 + np) = {-Thickness / 2, Height, zj + standoff};  np += 1;
  Point(p0 + np) = {-Thickness / 2, JointHeight, zj};        np += 1;
  If (j < NSegments)
    Point(p0 + np) = {-Thickness / 2, Height, zj - standoff}; np += 1;
  EndIf
EndFor
Point(p0 + np) = {-Thickness / 2, 0, tipZ};       np += 1;
l0 = newl;
For i In {0 : np - 1}
  Line(l0 + i) = {p0 + i, p0 + (i + 1) % np};
EndFor
cl = newll;
Curve Loop(cl) = {l0 : l0 + np - 1};
s0 = news;
Plane Surface(s0) = {cl};
seg[] = Extrude {Thickness, 0, 0} { Surface{s0}; };
parts[] = {seg[1]};

// ---- joints: half double cones about the z axis, swept from +x through +y to -x
For j In {1 : NSegments - 1}
  zj = -j * SegmentLength;
  q = newp;
  Point(q) = {0, 0, zj - StepHeight};
  Point(q + 1) = {Thickness / 2, 0, zj - StepHeight};
  Point(q + 2) = {OuterRadius, 0, zj};
  Point(q + 3) = {Thickness / 2, 0, zj + StepHeight};
  Point(q + 4) = {0, 0, zj + StepHeight};
  c = newl;
  For i In {0 : 4}
    Line(c + i) = {q + i, q + (i + 1) % 5};
  EndFor
  cl = newll;
  Curve Loop(cl) = {c : c + 4};
  s = news;
  Plane Surface(s) = {cl};
  b[] = Extrude {{0, 0, 1}, {0, 0, 0}, Pi} { Surface{s}; };
  parts[] += {b[1]};
EndFor

// ---- fixation plate
fix = newv;
Box(fix) = {-Thickness / 2 - FixationWidth, 0, -FixationWidth,
            Thickness + 2 * FixationWidth, Height + FixationWidth, FixationWidth};

body[] = BooleanUnion { Volume{fix}; Delete; } { Volume{parts[]}; Delete; };
If (#body[] != 1)
  Error("finger.geo: the union gave %g volumes", #body[]);
EndIf

Mesh.MeshSizeMax = lc;
Mesh.MeshSizeMin = lc / 4;
Mesh.MeshSizeFromPoints = 0;
Mesh.Optimize = 1;
Mesh.ElementOrder = 1;

eps = 1e-3;
big = OuterRadius + FixationWidth + Height;
base[] = Surface In BoundingBox {-big, -eps, -eps, big, big, eps};
tip[] = Surface In BoundingBox {-big, -eps, tipZ - eps, big, big, tipZ + eps};
surf[] = Abs(Boundary { Volume{body[0]}; });
surf[] -= {base[], tip[]};
Physical Surface("base") = {base[]};
Physical Surface("tip") = {tip[]};
Physical Surface("lateral") = {surf[]};
Physical Volume("finger") = {body[0]};
