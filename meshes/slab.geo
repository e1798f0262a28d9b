// A thin slab resting on a plane (issue "Contact at scale"): 0.3 x 0.3 x 0.01 m,
// unstructured tetrahedra of about 5 mm (gmsh -setnumber h VALUE), bottom face at z = 0.
DefineConstant[ L = 0.3, T = 0.01, h = 0.005 ];
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, L, L, T};
Mesh.CharacteristicLengthMax = h;
Mesh.CharacteristicLengthMin = h;
Physical Volume("slab") = {1};
