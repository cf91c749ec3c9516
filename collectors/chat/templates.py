"""Paraphrase templates of Chat-V2XBench questions and answers (several per item, chosen by seed).

Every answer template only re-words slots filled from the keyframe facts, so no paraphrase can
state something the facts do not. The words used for slot values are the ones the scorer
recognises (:data:`.scoring.VOCAB`).
"""

from __future__ import annotations

QUESTIONS: dict[str, tuple[str, ...]] = {
    "scene_description": (
        "Describe the driving scene around the ego vehicle: weather, time of day, traffic, road conditions and traffic signals.",
        "What is the overall driving environment like (weather and lighting, traffic density, road conditions, signal states)?",
        "Give a holistic description of the current scene from the ego and roadside views.",
    ),
    "traffic_light": (
        "Does a traffic light currently affect the ego vehicle? If so, what colour is it?",
        "Is there a traffic light controlling the ego's lane right now, and what is its colour?",
        "Is the ego vehicle governed by a traffic light at the moment? If yes, which colour does it show?",
    ),
    "critical_objects": (
        "Fusing the ego and roadside views, which one or two objects are the most critical for the ego vehicle? Give their ego-frame coordinates, their motion and their safety impact.",
        "Identify the most safety-relevant objects around the ego (at most two), where they are in the ego frame, how they move and how they affect the ego.",
        "Which objects matter most for the ego's safety right now, considering both the ego cameras and the roadside camera?",
    ),
    "rsu_to_ego": (
        "A {cls} is at ({x:.2f}, {y:.2f}, {z:.2f}) m in the roadside camera frame (x right, y down, z forward). Where is it in the ego frame (x forward, y left, z up)?",
        "A {cls} has coordinates ({x:.2f}, {y:.2f}, {z:.2f}) m in the roadside camera frame. Convert this position to the ego vehicle frame.",
        "In the RSU camera frame a {cls} is located at ({x:.2f}, {y:.2f}, {z:.2f}) m. What are its coordinates relative to the ego vehicle?",
    ),
    "speed_decision": (
        "What should the ego vehicle do with its speed now: accelerate, decelerate, keep its speed or stop?",
        "Choose the ego's speed decision: accelerate, decelerate, keep or stop.",
        "Given the current speed and navigation command, what is the right speed decision for the ego?",
    ),
    "path_decision": (
        "What path decision should the ego take next?",
        "Which path should the ego vehicle follow in the next seconds?",
        "Decide the ego's path: follow the lane, turn, go straight, change lanes or nudge around something?",
    ),
    "behavior": (
        "What should the ego vehicle do now, and what is the single most important reason?",
        "Decide the ego's immediate behaviour (speed and path) and justify it with the most important reason.",
        "Plan the ego's next move: speed decision, path decision and the key reason behind them.",
    ),
    "previous_command": (
        "What was the ego's navigation command in the previous frame?",
        "Which navigation command did the ego follow one frame ago?",
        "In the previous frame, what navigation command was the ego given?",
    ),
    "speed_trend": (
        "Over the last second, has the ego been accelerating, decelerating or keeping its speed?",
        "What is the ego vehicle's recent speed trend?",
        "Is the ego speeding up, slowing down or holding its speed compared with one second ago?",
    ),
}

WEATHER = {"clear": "clear", "cloudy": "cloudy", "rain": "rainy", "fog": "foggy"}
TIME = {"day": "daytime", "dusk": "dusk", "night": "night"}
DENSITY = {"light": "light traffic", "moderate": "moderate traffic", "heavy": "heavy traffic"}
CLASS = {"car": "car", "large_vehicle": "large vehicle", "pedestrian": "pedestrian",
         "bicycle": "cyclist", "traffic_cone": "traffic cone", "static_obstacle": "static obstacle"}
COMMAND = {"follow_lane": "follow the lane", "left": "turn left", "right": "turn right",
           "straight": "go straight", "change_lane_left": "change lane to the left",
           "change_lane_right": "change lane to the right"}
SPEED = {"accelerate": "accelerate", "decelerate": "decelerate", "keep": "keep the current speed",
         "stop": "stop"}
PATH = {"follow_lane": "follow the lane", "turn_left": "turn left", "turn_right": "turn right",
        "go_straight": "go straight", "change_lane_left": "change lane to the left",
        "change_lane_right": "change lane to the right", "nudge_left": "nudge to the left",
        "nudge_right": "nudge to the right"}
TREND = {"accelerating": "accelerating", "decelerating": "decelerating", "unchanged": "keeping its speed"}
MOTION = {"stationary": "stationary", "same_direction": "moving in the same direction as the ego",
          "oncoming": "oncoming", "crossing_left": "crossing toward the left",
          "crossing_right": "crossing toward the right"}
SEEN = {"both": "seen by the ego and the roadside unit", "ego": "seen by the ego only",
        "rsu": "seen only by the roadside unit"}

LIGHT_YES = (
    "Yes, a {c} traffic light controls the ego's lane, {d:.0f} m ahead.",
    "Yes. The light for the ego's lane is {c}, with the stop line {d:.0f} m away.",
    "Yes, it is {c}; the stop line is {d:.0f} m ahead.",
)
LIGHT_NO = (
    "No, no traffic light affects the ego vehicle right now.",
    "No. The ego is not governed by a traffic light at the moment.",
    "No, there is no traffic light controlling the ego's lane now.",
)
SCENE = (
    "It is {time} with {weather} weather. There is {density} ({nv} vehicles within 50 m, {np} pedestrians within 30 m). {road} {signal}",
    "The scene is {weather} at {time}, with {density} around the ego: {nv} vehicles nearby and {np} pedestrians. {road} {signal}",
    "Weather: {weather}; time of day: {time}; {density} with {nv} vehicles and {np} pedestrians close by. {road} {signal}",
)
ROAD_CLEAR = ("The road ahead is free of obstacles.", "No obstacles or construction on the road ahead.")
ROAD_OBST = ("There are {n} obstacles on the road ahead ({what}).", "The road ahead has {n} obstacles: {what}.")
CONSTRUCTION = " Traffic cones mark a construction zone."
CRIT_NONE = (
    "No object is critical right now; the ego's path is clear.",
    "There is no critical object near the ego's path at the moment.",
)
CRIT_ONE = (
    "The {cls} #{id} at ({x:.1f}, {y:.1f}) m, {motion} at {v:.1f} m/s, {seen}; {impact}.",
    "{Cls} #{id}: located at ({x:.1f}, {y:.1f}) m in the ego frame, {motion} ({v:.1f} m/s), {seen}. Impact: {impact}.",
)
IMPACT = {
    "collision_risk": "it comes within {m:.1f} m of the ego in about {s:.1f} s (collision risk)",
    "collision_risk_behind": "it closes in from behind, within {m:.1f} m of the ego in about {s:.1f} s (collision risk)",
    "in_path": "it is in the ego's path {gap:.0f} m ahead",
    "monitor": "it is near the ego's path with no immediate conflict, so the ego monitors it",
}
RESPONSE = {"decelerate": ", so the ego slows down", "stop": ", so the ego stops"}
REASON = {  # clauses: "because <reason>"; keys are the behaviour's effective reasons
    "free": "the road ahead is clear",
    "leader": "a slower {cls} is ahead in the same lane",
    "follow": "it follows the {cls} ahead at a safe gap",
    "red": "the traffic light ahead is red",
    "yellow": "the traffic light ahead is yellow",
    "stop_sign": "there is a stop sign at the junction ahead",
    "yield": "the ego must yield to crossing traffic at the junction",
    "conflict": "a {cls} is predicted to cross the ego's path",
    "clear_until": "the way is clear up to the {what} ahead",
    "slow_zone": "a curve or a lower speed limit is ahead",
    "other": "of the current traffic situation",
}
STOP_THINGS = {"red": "red light", "yellow": "yellow light", "stop_sign": "stop sign",
               "yield": "junction", "conflict": "conflict zone"}
BEHAVIOR = (
    "The ego should {speed} and {path}, because {reason}.",
    "Speed decision: {speed}; path decision: {path}. The key reason is that {reason}.",
    "{Speed} and {path}: {reason}.",
)
ALIGN = (
    "In the ego frame the {cls} is at ({x:.2f}, {y:.2f}, {z:.2f}) m.",
    "({x:.2f}, {y:.2f}, {z:.2f}) m relative to the ego vehicle.",
    "It is at x = {x:.2f} m, y = {y:.2f} m, z = {z:.2f} m in the ego frame.",
)
CLOSED = {
    "speed_decision": ("The ego should {v}.", "{V}.", "Decision: {v}."),
    "path_decision": ("The ego should {v}.", "{V}.", "Path: {v}."),
    "previous_command": ("The previous command was to {v}.", "{V}.", "In the previous frame the command was: {v}."),
    "speed_trend": ("The ego is {v}.", "{V}.", "Compared with one second ago the ego is {v}."),
}
