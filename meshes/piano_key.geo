// softdiff piano key for the pianist scene (configs/pianist.yaml): a straight wooden-like key
// that pivots on a balance rail, like the key of an upright or grand piano without its action.
// UNITS: millimetres (scenes load it with mesh_scale: 0.001).
//
// Frame: x across the key (symmetric about x = 0), y along the key from the front end
// (y = 0, the player's side) to the back end (y = FrontArm + RearArm), z up with the top
// face at z = 0 and the bottom face at z = -KeyHeight.
//  * The key is a box KeyWidth x (FrontArm + RearArm) x KeyHeight, meshed as structured
//    tetrahedra (like beam.geo): a transfinite cross-section extruded in layers of about
//    LayerLength along y.
//  * The balance pin is the bottom edge at y = FrontArm: a layer boundary, so it carries a
//    line of mesh nodes (physical curve "hinge"). Fixing those nodes makes a hinge: the key
//    rotates about that line. The rear arm is longer than the front arm, so under gravity
//    the key's back end rests on a back rail (an obstacle of the scene) and a finger
//    pressing the front arm tilts it; released, it falls back onto the rail.
// No piano-key geometry is public in the upstream repositories (see meshes/README.md): the
// sizes are those of a real white key (22-23 mm wide) with a shortened body.
//
// Override any parameter with: gmsh -3 piano_key.geo -setnumber NAME VALUE
DefineConstant[
  KeyWidth    = {22,  Name "Key/KeyWidth (x)"},
  KeyHeight   = {12,  Name "Key/KeyHeight (z)"},
  FrontArm    = {60,  Name "Key/FrontArm (front end to the pivot, y)"},
  RearArm     = {80,  Name "Key/RearArm (pivot to the back end, y)"},
  NWidth      = {4,   Name "Mesh/NWidth (elements across x)"},
  NHeight     = {2,   Name "Mesh/NHeight (elements across z)"},
  LayerLength = {5,   Name "Mesh/LayerLength (target element length along y)"}
];
nf = Round(FrontArm / LayerLength);
nr = Round(RearArm / LayerLength);
If (nf < 1 || nr < 1)
  Error("piano_key.geo: FrontArm and RearArm must be at least LayerLength/2");
EndIf

// cross-section in the plane y = 0 (the front face)
Point(1) = {-KeyWidth / 2, 0, -KeyHeight};
Point(2) = { KeyWidth / 2, 0, -KeyHeight};
Point(3) = { KeyWidth / 2, 0, 0};
Point(4) = {-KeyWidth / 2, 0, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Transfinite Curve{1, 3} = NWidth + 1;
Transfinite Curve{2, 4} = NHeight + 1;
Transfinite Surface{1} Alternate;

front[] = Extrude {0, FrontArm, 0} { Surface{1}; Layers{nf}; };   // front[0]: the pivot plane
rear[] = Extrude {0, RearArm, 0} { Surface{front[0]}; Layers{nr}; };

eps = 1e-6;
L = FrontArm + RearArm;
hinge[] = Curve In BoundingBox {-KeyWidth, FrontArm - eps, -KeyHeight - eps,
                                KeyWidth, FrontArm + eps, -KeyHeight + eps};
top[] = Surface In BoundingBox {-KeyWidth, -eps, -eps, KeyWidth, L + eps, eps};
If (#hinge[] != 1 || #top[] != 2)
  Error("piano_key.geo: found %g hinge curves and %g top faces", #hinge[], #top[]);
EndIf
Physical Curve("hinge") = {hinge[]};
Physical Surface("front") = {1};
Physical Surface("back") = {rear[0]};
Physical Surface("top") = {top[]};
Physical Volume("key") = {front[1], rear[1]};
