// Two 10 mm cubes side by side, fused into one conforming mesh (BooleanFragments),
// with their shared internal face x = 0.01 tagged as the physical surface
// "interface": a surface group whose triangles are interior faces of the body (each
// shared by two tetrahedra), for tests/app/test_cli_actuators.cpp. Meshed at test time:
//   gmsh -3 two_boxes_interface.geo -format msh41 -o out.msh
SetFactory("OpenCASCADE");
Mesh.CharacteristicLengthMax = 0.004;
Mesh.ElementOrder = 1;
Box(1) = {0, 0, 0, 0.01, 0.01, 0.01};
Box(2) = {0.01, 0, 0, 0.01, 0.01, 0.01};
BooleanFragments{ Volume{1, 2}; Delete; }{}
e = 1e-5;
interface[] = Surface In BoundingBox{0.01 - e, -e, -e, 0.01 + e, 0.01 + e, 0.01 + e};
outer[] = Surface In BoundingBox{0.02 - e, -e, -e, 0.02 + e, 0.01 + e, 0.01 + e};
Physical Surface("interface") = {interface[]};
Physical Surface("end") = {outer[]};
Physical Volume("solid") = {Volume{:}};
