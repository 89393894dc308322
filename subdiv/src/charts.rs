//! Characteristic-map vertex charts (Ying et al. 2001, end of §4.2). Filled in below.
pub struct Charts;
pub struct VertexChart;
pub struct ChartPoint;
