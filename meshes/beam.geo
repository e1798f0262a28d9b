// Rectangular beam along +x, clamped face at x = 0, structured tetrahedra.
// Parameters (override with gmsh -setnumber NAME VALUE):
//   L, W, H: length (x), width (y), height (z) in metres
//   n: elements across the height (and the width); n * L / H along the length
DefineConstant[ L = 0.2, W = 0.02, H = 0.02, n = 4 ];
nl = Round(n * L / H);
Point(1) = {0, 0, 0};
Point(2) = {0, W, 0};
Point(3) = {0, W, H};
Point(4) = {0, 0, H};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Transfinite Curve{1, 2, 3, 4} = n + 1;
Transfinite Surface{1} Alternate;
out[] = Extrude {L, 0, 0} { Surface{1}; Layers{nl}; };
Physical Surface("clamp") = {1};
Physical Surface("tip") = {out[0]};
Physical Volume("beam") = {out[1]};
