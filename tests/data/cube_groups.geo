// A 1 x 0.5 x 0.25 box with named physical groups of every dimension, for the
// Gmsh reader tests (tests/io/test_gmsh_msh.cpp). Meshed at test time with the
// real gmsh: `gmsh -3 cube_groups.geo -format msh41 -o a41.msh`.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 1, 0.5, 0.25};
Mesh.CharacteristicLengthMax = 0.2;
Mesh.ElementOrder = 1;

// OpenCASCADE numbers the box faces x=0, x=1, y=0, y=1, z=0, z=top (1..6) and
// vertex 7 is the corner (1, 0.5, 0.25); curve 1 is the edge x=0, y=0.
Physical Surface("clamp", 11) = {1};
Physical Surface("top", 12) = {6};
Physical Volume("solid", 21) = {1};
Physical Point("tip", 31) = {7};
Physical Curve("edge", 41) = {1};
