"""V2XIntersection: the V2XBench cooperative driving simulator."""
