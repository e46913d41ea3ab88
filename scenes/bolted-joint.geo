// A bolted lap joint after the paper's second example (Boucard, Odievre & Gatuingt 2011,
// Section 5): two sandwich plates, each glued to a steel part; the two steel parts overlap and
// are held by three bolts. The paper gives no dimensions:
// these are ours. One conforming mesh of the assembly (BooleanFragments); glissade splits it
// into bodies by physical volume and joins them by the interfaces of the scene.
// Physical volumes: sandwich_a, metal_a, metal_b, sandwich_b, and per bolt i nut_side_i (nut
// and lower shank) and head_side_i (head and upper shank).
// Physical surfaces: clamp (sandwich_a's free end), pull (sandwich_b's free end), glue_a,
// glue_b (sandwich / steel part), lap (steel part on steel part), and per bolt i: head_i (head
// on metal_b), nut_i (nut on metal_a), hole_a_i, hole_b_i (shank in the holes), cut_i (across
// the shank, where the prestress acts).
// Made by (pip install gmsh; gmsh 4.15):
//   gmsh bolted-joint.geo -3 -format msh41 -bin -o bolted-joint-tiny.msh
SetFactory("OpenCASCADE");
DefineConstant[
  t = {0.004, Name "thickness of each part (m)"},
  lm = {0.04, Name "length of a steel part (m)"},
  lap = {0.02, Name "overlap of the steel parts (m)"},
  ls = {0.04, Name "length of a sandwich plate (m)"},
  pitch = {0.02, Name "bolt pitch (m)"},
  rs = {0.003, Name "shank radius (m)"},
  rh = {0.005, Name "head and nut radius (m)"},
  hh = {0.003, Name "head and nut height (m)"},
  h = {0.01, Name "element size (m)"},
  hb = {0.004, Name "element size at the bolts (m)"}
];
w = 3 * pitch;
xc = lm - lap / 2;
Box(1) = {-ls, 0, 0, ls, w, t};              // sandwich_a
Box(2) = {0, 0, 0, lm, w, t};                // metal_a
Box(3) = {lm - lap, 0, t, lm, w, t};         // metal_b
Box(4) = {2 * lm - lap, 0, t, ls, w, t};     // sandwich_b
// Each bolt in two volumes cut across its shank at z = t (the lap plane): the nut with the
// lower shank, the head with the upper shank; the prestress interface joins them.
For i In {1:3}
  yc = (i - 0.5) * pitch;
  Cylinder(10 + i) = {xc, yc, 0, 0, 0, t, rs};
  Cylinder(30 + i) = {xc, yc, -hh, 0, 0, hh, rh};
  BooleanUnion(40 + i) = { Volume{10 + i}; Delete; }{ Volume{30 + i}; Delete; };
  Cylinder(60 + i) = {xc, yc, t, 0, 0, t, rs};
  Cylinder(20 + i) = {xc, yc, 2 * t, 0, 0, hh, rh};
  BooleanUnion(70 + i) = { Volume{60 + i}; Delete; }{ Volume{20 + i}; Delete; };
EndFor
BooleanDifference(50) = { Volume{2}; Delete; }{ Volume{41, 42, 43}; };
BooleanDifference(51) = { Volume{3}; Delete; }{ Volume{71, 72, 73}; };
BooleanFragments{ Volume{1, 50, 51, 4, 41, 42, 43, 71, 72, 73}; Delete; }{}
e = 1e-6;
Physical Volume("sandwich_a") = Volume In BoundingBox{-ls - e, -e, -e, e, w + e, t + e};
Physical Volume("metal_a") = Volume In BoundingBox{-e, -e, -e, lm + e, w + e, t + e};
Physical Volume("metal_b") = Volume In BoundingBox{lm - lap - e, -e, t - e, 2 * lm - lap + e, w + e, 2 * t + e};
Physical Volume("sandwich_b") = Volume In BoundingBox{2 * lm - lap - e, -e, t - e, 2 * lm - lap + ls + e, w + e, 2 * t + e};
Physical Surface("clamp") = Surface In BoundingBox{-ls - e, -e, -e, -ls + e, w + e, t + e};
Physical Surface("pull") = Surface In BoundingBox{2 * lm - lap + ls - e, -e, t - e, 2 * lm - lap + ls + e, w + e, 2 * t + e};
Physical Surface("glue_a") = Surface In BoundingBox{-e, -e, -e, e, w + e, t + e};
Physical Surface("glue_b") = Surface In BoundingBox{2 * lm - lap - e, -e, t - e, 2 * lm - lap + e, w + e, 2 * t + e};
Physical Surface("lap") = Surface In BoundingBox{lm - lap - e, -e, t - e, lm + e, w + e, t + e};
bolts() = {};
For i In {1:3}
  yc = (i - 0.5) * pitch;
  nut() = Volume In BoundingBox{xc - rh - e, yc - rh - e, -hh - e, xc + rh + e, yc + rh + e, t + e};
  head() = Volume In BoundingBox{xc - rh - e, yc - rh - e, t - e, xc + rh + e, yc + rh + e, 2 * t + hh + e};
  bolts() += {nut(), head()};
  Physical Volume(Sprintf("nut_side_%g", i)) = nut();
  Physical Volume(Sprintf("head_side_%g", i)) = head();
  cut() = Surface In BoundingBox{xc - rs - e, yc - rs - e, t - e, xc + rs + e, yc + rs + e, t + e};
  Physical Surface(Sprintf("cut_%g", i)) = cut();
  Physical Surface(Sprintf("head_%g", i)) = Surface In BoundingBox{xc - rh - e, yc - rh - e, 2 * t - e, xc + rh + e, yc + rh + e, 2 * t + e};
  Physical Surface(Sprintf("nut_%g", i)) = Surface In BoundingBox{xc - rh - e, yc - rh - e, -e, xc + rh + e, yc + rh + e, e};
  // the shank's cylinder in each part (the cut's disk lies in the same boxes)
  hole() = Surface In BoundingBox{xc - rs - e, yc - rs - e, -e, xc + rs + e, yc + rs + e, t + e};
  hole() -= cut();
  Physical Surface(Sprintf("hole_a_%g", i)) = hole();
  hole() = Surface In BoundingBox{xc - rs - e, yc - rs - e, t - e, xc + rs + e, yc + rs + e, 2 * t + e};
  hole() -= cut();
  Physical Surface(Sprintf("hole_b_%g", i)) = hole();
EndFor
MeshSize{:} = h;
MeshSize{PointsOf{Volume{bolts()};}} = hb;
