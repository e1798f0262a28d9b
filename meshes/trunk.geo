// softdiff Trunk robot: the SoftRobots "Trunk" tutorial body, rebuilt from its dimensions.
// UNITS: millimetres (like the SoftRobots scene; scenes load it with mesh_scale: 0.001).
//
// A solid of revolution about +z, base disk at z = 0, tip disk at z = TrunkLength:
// the envelope is a cone of radius BaseRadius at z = 0 and TipRadius at the tip, cut by
// NGroove V-shaped circumferential grooves (the "necks" between the wide disks). Groove k
// (k = 1..NGroove) is centred at z = GrooveZ0 + (k-1)*GroovePitch, its bottom is a circle of
// radius NeckRadiusA (k <= NNeckA) or NeckRadiusB (k > NNeckA), and its two flanks are cones
// whose generator makes the angle FlankAngle<k> (degrees) with the z axis (90 would be a flat
// radial wall): radius = neck + tan(FlankAngle)*|z - zc| until it meets the envelope.
// These values are measurements of the SoftRobots outline (see meshes/README.md).
//
// Cables (SoftRobots trunk.py): d = normalize(0, CableLength2 - CableLength1, TrunkLength);
// the points of pair j (j = 0..9) sit at radius CableRadius0 + d.y*CablePitch*j and heights
// CableZLow + d.z*CablePitch*j and CableZHigh + d.z*CablePitch*j, i.e. 3 mm either side of
// groove j+1, on its flanks. In the upstream mesh 11 of the 20 points of each long cable lie
// 0.01-0.8 mm outside the body (grooves 2-7 are too wide for them). With FitCables = 1
// (default) a flank is made just steep enough that every cable point lies at least
// CableClearance inside it (distance normal to the flank; 0.25 mm is what the upstream
// outline gives at groove 1, which is kept as measured). Only the flank angles change; the
// neck radii, groove positions and the envelope do not. FitCables = 0: the measured outline.
//
// Override any parameter with: gmsh -3 trunk.geo -setnumber NAME VALUE
SetFactory("OpenCASCADE");

DefineConstant[
  TrunkLength = {195, Name "Trunk/TrunkLength (lengthTrunk)"},
  BaseRadius  = {13,  Name "Trunk/BaseRadius"},
  TipRadius   = {5,   Name "Trunk/TipRadius"},
  NGroove     = {10,  Name "Trunk/NGroove"},
  GrooveZ0    = {24,  Name "Trunk/GrooveZ0"},
  GroovePitch = {17.5, Name "Trunk/GroovePitch"},
  NNeckA      = {4,   Name "Trunk/NNeckA"},
  NeckRadiusA = {2.5, Name "Trunk/NeckRadiusA"},
  NeckRadiusB = {2.0, Name "Trunk/NeckRadiusB"},
  FlankAngle1 = {70, Name "Trunk/FlankAngle1"},
  FlankAngle2 = {65, Name "Trunk/FlankAngle2"},
  FlankAngle3 = {60, Name "Trunk/FlankAngle3"},
  FlankAngle4 = {60, Name "Trunk/FlankAngle4"},
  FlankAngle5 = {60, Name "Trunk/FlankAngle5"},
  FlankAngle6 = {50, Name "Trunk/FlankAngle6"},
  FlankAngle7 = {50, Name "Trunk/FlankAngle7"},
  FlankAngle8 = {50, Name "Trunk/FlankAngle8"},
  FlankAngle9 = {50, Name "Trunk/FlankAngle9"},
  FlankAngle10 = {50, Name "Trunk/FlankAngle10"},
  // cable path parameters of SoftRobots trunk.py (length1, length2, lengthTrunk above)
  CableRadius0 = {10, Name "Cables/CableRadius0"},
  CableLength1 = {10, Name "Cables/CableLength1 (length1)"},
  CableLength2 = {2,  Name "Cables/CableLength2 (length2)"},
  CablePitch   = {17.5, Name "Cables/CablePitch"},
  CableZLow    = {21, Name "Cables/CableZLow"},
  CableZHigh   = {27, Name "Cables/CableZHigh"},
  FitCables      = {1,   Choices {0, 1}, Name "Cables/FitCables"},
  CableClearance = {0.25, Name "Cables/CableClearance"},
  // mesh size: elements per 2*pi of curvature, and bounds (mm)
  MeshCurvature = {8,  Name "Mesh/MeshCurvature"},
  MeshSizeMax   = {6,   Name "Mesh/MeshSizeMax"},
  MeshSizeMin   = {0.5, Name "Mesh/MeshSizeMin"}
];

If (NGroove > 10)
  Error("trunk.geo defines FlankAngle1..FlankAngle10 only");
EndIf
flank[] = {FlankAngle1, FlankAngle2, FlankAngle3, FlankAngle4, FlankAngle5,
           FlankAngle6, FlankAngle7, FlankAngle8, FlankAngle9, FlankAngle10};

taper = (BaseRadius - TipRadius) / TrunkLength;       // envelope: R(z) = BaseRadius - taper*z
cableNorm = Sqrt((CableLength2 - CableLength1)^2 + TrunkLength^2);
cableDy = (CableLength2 - CableLength1) / cableNorm;  // d.y of the cable direction
cableDz = TrunkLength / cableNorm;                    // d.z

// Profile in the x-z half plane (x = radius), counter-clockwise, revolved about z.
p = newp;
Point(p) = {0, 0, 0};
Point(p + 1) = {BaseRadius, 0, 0};
np = 2;
zprev = 0;                                            // top of the previous groove
For k In {0 : NGroove - 1}
  zc = GrooveZ0 + k * GroovePitch;
  rb = (k < NNeckA) ? NeckRadiusA : NeckRadiusB;
  s = Tan(flank[k] * Pi / 180);
  If (FitCables)
    // cable pair k: radius and the distance of its two points from the groove centre
    rc = CableRadius0 + cableDy * CablePitch * k;
    dzc = Min(zc - (CableZLow + cableDz * CablePitch * k), (CableZHigh + cableDz * CablePitch * k) - zc);
    If (dzc > 0)
      // smallest slope sf with (rb + sf*dzc - rc) * cos(atan(sf)) = CableClearance, i.e.
      // the point is CableClearance from the flank cone, measured normal to the flank
      // (fixed-point iteration; it contracts since CableClearance << dzc)
      sf = (rc - rb) / dzc;
      For it In {1 : 30}
        sf = (rc - rb + CableClearance * Sqrt(1 + sf^2)) / dzc;
      EndFor
      s = Max(s, sf);
    EndIf
  EndIf
  zlo = (rb + s * zc - BaseRadius) / (s - taper);     // lower flank meets the envelope
  zhi = (BaseRadius - rb + s * zc) / (s + taper);     // upper flank meets the envelope
  If (zlo <= zprev || zhi >= TrunkLength)
    Error("trunk.geo: groove %g (z %g..%g) overlaps its neighbour or an end face", k + 1, zlo, zhi);
  EndIf
  zprev = zhi;
  Point(p + np) = {BaseRadius - taper * zlo, 0, zlo};
  Point(p + np + 1) = {rb, 0, zc};
  Point(p + np + 2) = {BaseRadius - taper * zhi, 0, zhi};
  np += 3;
  Printf("trunk.geo: groove %g at z = %g: neck radius %g, flank angle %g deg (measured %g), z %g..%g",
         k + 1, zc, rb, Atan(s) * 180 / Pi, flank[k], zlo, zhi);
EndFor
Point(p + np) = {TipRadius, 0, TrunkLength};
Point(p + np + 1) = {0, 0, TrunkLength};
np += 2;

l = newl;
For i In {0 : np - 1}
  Line(l + i) = {p + i, p + (i + 1) % np};
EndFor
Curve Loop(1) = {l : l + np - 1};
Plane Surface(1) = {1};
body[] = Extrude {{0, 0, 1}, {0, 0, 0}, 2 * Pi} { Surface{1}; };
vol = body[1];

Mesh.MeshSizeFromCurvature = MeshCurvature;
Mesh.MeshSizeMax = MeshSizeMax;
Mesh.MeshSizeMin = MeshSizeMin;
Mesh.Algorithm = 1;          // MeshAdapt surfaces: no slivers with the defaults (Frontal-Delaunay gave q_min 0.04)
Mesh.Optimize = 1;
Mesh.ElementOrder = 1;

eps = 1e-3;
base[] = Surface In BoundingBox {-BaseRadius - eps, -BaseRadius - eps, -eps, BaseRadius + eps, BaseRadius + eps, eps};
tip[] = Surface In BoundingBox {-TipRadius - eps, -TipRadius - eps, TrunkLength - eps, TipRadius + eps, TipRadius + eps, TrunkLength + eps};
lateral[] = Abs(Boundary { Volume{vol}; });
lateral[] -= {base[], tip[]};
Physical Surface("base") = {base[]};
Physical Surface("tip") = {tip[]};
Physical Surface("lateral") = {lateral[]};
Physical Volume("trunk") = {vol};
