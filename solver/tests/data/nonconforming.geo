// The blocks of bar.geo meshed separately, the upper one finer: their "joint" faces do not
// match. Made by: gmsh nonconforming.geo -3 -format msh41 -o nonconforming.msh
SetFactory("OpenCASCADE");
a = 0.02;
Box(1) = {0, 0, 0, a, a, a};
Box(2) = {0, 0, a, a, a, a};
e = 1e-6;
Physical Volume("lower") = {1};
Physical Volume("upper") = {2};
Physical Surface("joint") = Surface In BoundingBox{-e, -e, a - e, a + e, a + e, a + e};
MeshSize{PointsOf{Volume{1};}} = 0.01;
MeshSize{PointsOf{Volume{2};}} = 0.006;
