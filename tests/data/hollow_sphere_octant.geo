// One octant (x, y, z >= 0) of a hollow sphere, inner radius a, outer radius b, for
// the pressurized thick-walled sphere validation (tests/actuation/validation_pressure.cpp).
// Meshed at test time with the real gmsh, uniform element size h:
//   gmsh -3 hollow_sphere_octant.geo -setnumber h 0.00125 -format msh41 -o out.msh
// Physical groups: "cavity" the inner spherical surface (an open surface: its edges
// lie on the symmetry planes), "sym_x", "sym_y", "sym_z" the symmetry planes x = 0,
// y = 0, z = 0, "shell" the volume.
SetFactory("OpenCASCADE");
DefineConstant[ a = 0.01, b = 0.02, h = 0.0025 ];
Mesh.CharacteristicLengthMin = h;
Mesh.CharacteristicLengthMax = h;
Mesh.ElementOrder = 1;
Sphere(1) = {0, 0, 0, b};
Sphere(2) = {0, 0, 0, a};
Box(3) = {0, 0, 0, b, b, b};
BooleanDifference(4) = { Volume{1}; Delete; }{ Volume{2}; Delete; };
BooleanIntersection(5) = { Volume{4}; Delete; }{ Volume{3}; Delete; };
// OpenCASCADE bounding boxes are padded by ~1e-7: select with a margin well above it.
e = 1e-3 * b;
inner[] = Surface In BoundingBox{-e, -e, -e, a + e, a + e, a + e};
sx[] = Surface In BoundingBox{-e, -e, -e, e, b + e, b + e};
sy[] = Surface In BoundingBox{-e, -e, -e, b + e, e, b + e};
sz[] = Surface In BoundingBox{-e, -e, -e, b + e, b + e, e};
If (#inner[] != 1 || #sx[] != 1 || #sy[] != 1 || #sz[] != 1)
  Error("hollow_sphere_octant.geo: expected one surface per group, got %g %g %g %g", #inner[], #sx[], #sy[], #sz[]);
EndIf
Physical Surface("cavity") = {inner[]};
Physical Surface("sym_x") = {sx[]};
Physical Surface("sym_y") = {sy[]};
Physical Surface("sym_z") = {sz[]};
Physical Volume("shell") = {5};
