// Two stacked steel blocks, 0.02 x 0.02 x 0.02 m each, meshed as one conforming mesh:
// physical volumes "lower" and "upper"; physical surfaces "base" (z = 0), "joint" (z = 0.02,
// shared by both volumes) and "top" (z = 0.04). The committed meshes are made by
// (pip install gmsh; gmsh 4.15):
//   gmsh bar.geo -3 -format msh41 -o bar-tet.msh                       (tetrahedra, ASCII)
//   gmsh bar.geo -3 -format msh41 -bin -o bar-tet-bin.msh              (the same, binary)
//   gmsh bar.geo -3 -setnumber hex 1 -format msh41 -bin -o bar-hex.msh (hexahedra, binary)
//   gmsh bar.geo -3 -order 2 -setnumber h 0.02 -format msh41 -o bar-tet10.msh (10-node tetrahedra)
SetFactory("OpenCASCADE");
DefineConstant[ hex = 0, h = 0.008 ];
a = 0.02;
Box(1) = {0, 0, 0, a, a, a};
Box(2) = {0, 0, a, a, a, a};
BooleanFragments{ Volume{1}; Delete; }{ Volume{2}; Delete; }
e = 1e-6;
Physical Volume("lower") = Volume In BoundingBox{-e, -e, -e, a + e, a + e, a + e};
Physical Volume("upper") = Volume In BoundingBox{-e, -e, a - e, a + e, a + e, 2 * a + e};
Physical Surface("base") = Surface In BoundingBox{-e, -e, -e, a + e, a + e, e};
Physical Surface("joint") = Surface In BoundingBox{-e, -e, a - e, a + e, a + e, a + e};
Physical Surface("top") = Surface In BoundingBox{-e, -e, 2 * a - e, a + e, a + e, 2 * a + e};
If (hex)
  // 4 x 4 x 4 hexahedra per block
  Transfinite Curve{:} = 5;
  Transfinite Surface{:};
  Recombine Surface{:};
  Transfinite Volume{:};
Else
  MeshSize{:} = h;
EndIf
