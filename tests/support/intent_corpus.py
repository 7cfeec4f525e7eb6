"""Hand-labelled stage-2 texts for the intent reader (rules ``intent@lightemma/1``, docs/parsing.md#intents).

Each entry is ``(text, longitudinal, lateral)``: the class a careful reader takes from the *planned* part of
the text (not its recap of the past), or ``"unknown"`` where the plan on that axis is negated, conditional,
hedged, contradictory, about another road user, or not stated. The styles are those real models write:
terse, verbose with a recap first, Markdown sections, with conditionals and hedges.
"""

from __future__ import annotations

U = "unknown"

# fmt: off
CORPUS: list[tuple[str, str, str]] = [
    # ---- terse, imperative
    ("Maintain speed and follow the lane.", "keep_speed", "follow_lane"),
    ("Slow down and stop.", "stop", U),
    ("Decelerate, keep lane.", "decelerate", "follow_lane"),
    ("Accelerate and go straight.", "accelerate", "follow_lane"),
    ("Turn left at the intersection while slowing down.", "decelerate", "turn_left"),
    ("Turn right.", U, "turn_right"),
    ("Keep lane, constant speed.", "keep_speed", "follow_lane"),
    ("Stay stopped.", "stay_stopped", U),
    ("Remain stationary at the red light.", "stay_stopped", U),
    ("Start moving and continue straight.", "start", "follow_lane"),
    ("Change lanes to the left.", U, "change_lane_left"),
    ("Merge into the right lane and accelerate.", "accelerate", "change_lane_right"),
    ("Brake gently.", "decelerate", U),
    ("Cruise in the current lane.", "keep_speed", "follow_lane"),
    ("Speed up slightly and keep to the lane.", "accelerate", "follow_lane"),
    ("Come to a complete stop.", "stop", U),
    ("Hold position.", "stay_stopped", U),
    ("Go straight at a steady speed.", "keep_speed", "follow_lane"),
    ("Gradually slow down, stay in lane.", "decelerate", "follow_lane"),
    ("Make a left turn.", U, "turn_left"),
    ("Keep straight.", U, "follow_lane"),
    ("Pull away from the stop line and go straight.", "start", "follow_lane"),
    ("Reduce speed.", "decelerate", U),
    ("Increase speed to about 10 m/s.", "accelerate", U),
    ("Maintain current speed.", "keep_speed", U),
    ("Continue at the current speed.", "keep_speed", U),
    ("Speeds 5.0, 5.2, 5.4, 5.6, 5.8, 6.0; curvatures 0, 0, 0, 0, 0, 0. Accelerate.", "accelerate", U),
    # ---- recap first, then the plan (the prompt's order)
    (("The ego vehicle has been decelerating slightly over the past 3 seconds while following its lane. "
     "Given the clear road ahead, it should now accelerate gently and continue in its lane."), "accelerate", "follow_lane"),
    (("The ego vehicle was accelerating by about 1 m/s² and driving straight. "
     "Over the next 3 seconds it should maintain its speed and keep its lane."), "keep_speed", "follow_lane"),
    ("Recently the vehicle was stopped at the light. The light is now green, so the ego vehicle should start moving and proceed straight through the intersection.",
     "start", "follow_lane"),
    ("The ego vehicle has been turning left at low speed. It should complete the left turn and then accelerate.", "accelerate", "turn_left"),
    ("The ego vehicle was decelerating from 8 m/s to 5 m/s. It should come to a stop behind the bus.", "stop", U),
    (("Past behaviour: the car has been travelling at a constant speed of about 9 m/s in its lane. "
     "For the next 3 seconds, the ego vehicle should slow down to prepare for the crosswalk and stay in its lane."), "decelerate", "follow_lane"),
    ("The ego vehicle has been stationary for the last 3 seconds. It should remain stopped because pedestrians are crossing.",
     "stay_stopped", U),
    ("The vehicle was turning right, with a curvature of about -0.05. Next, it should straighten out and go straight while keeping a steady speed.",
     "keep_speed", "follow_lane"),
    ("Previously the ego vehicle accelerated moderately and changed lanes to the left. Now it should maintain speed and follow the lane.",
     "keep_speed", "follow_lane"),
    ("The ego vehicle has been slowing down. It should continue to decelerate and come to a stop at the stop line.", "stop", U),
    ("The ego vehicle has been decelerating at about 0.5 m/s² while following its lane.", U, U),
    ("Over the last 3 seconds the ego vehicle was accelerating and turning left.", U, U),
    ("The ego vehicle is currently decelerating and following the lane.", U, U),
    ("The ego vehicle has been keeping a constant speed. Going forward, it should accelerate and change lanes to the right to pass the parked truck.",
     "accelerate", "change_lane_right"),
    ("The vehicle has been decelerating gently, about 0.3 m/s², and following its lane. Given the red light ahead, the ego vehicle should decelerate more firmly and come to a complete stop before the stop line, staying in its lane.",
     "stop", "follow_lane"),
    # ---- verbose, single paragraph
    (("Given the current scene with active construction and a police officer directing traffic in the middle of the road, "
     "the ego vehicle should significantly decelerate by approximately 2-3 m/s² to prepare for possible stopping. "
     "The vehicle should continue following the lane while being prepared to come to a complete stop if directed by the officer."),
     "decelerate", "follow_lane"),
    ("Considering the vehicles ahead are moving smoothly and the traffic light is green, the ego vehicle should maintain its current speed of around 7 m/s and keep following its lane.",
     "keep_speed", "follow_lane"),
    ("The road curves gently to the right ahead. The ego vehicle should turn right following the curve and reduce its speed slightly.",
     "decelerate", U),
    ("With a cyclist on the right and a clear left lane, the ego vehicle should change into the left lane and keep its speed.",
     "keep_speed", "change_lane_left"),
    ("The ego vehicle should yield to the crossing pedestrians by coming to a full stop, then remain stopped until they have passed.",
     "stop", U),
    ("It would be best to accelerate moderately to match the flow of traffic while keeping to the current lane.", "accelerate", "follow_lane"),
    ("The ego vehicle will make a right turn at the upcoming intersection, slowing down to do so safely.", "decelerate", "turn_right"),
    ("The recommended action is to maintain a steady pace and continue straight ahead.", "keep_speed", "follow_lane"),
    ("I will speed up a little and continue in the current lane.", "accelerate", "follow_lane"),
    ("We should brake and turn left into the parking lot.", "decelerate", "turn_left"),
    ("The ego vehicle needs to slow down and merge left because the right lane ends.", "decelerate", "change_lane_left"),
    ("The ego vehicle must stop for the red light.", "stop", U),
    ("The ego vehicle should keep waiting at the intersection.", "stay_stopped", U),
    ("The ego vehicle should begin moving forward slowly as the queue clears, following its lane.", "start", "follow_lane"),
    ("The ego vehicle should continue driving straight at the same speed.", "keep_speed", "follow_lane"),
    ("The ego vehicle should steer left into the adjacent lane to overtake.", U, "change_lane_left"),
    ("The ego vehicle should bear right and slow down.", "decelerate", "turn_right"),
    ("The ego vehicle should stay in its lane and ease off the accelerator.", "decelerate", "follow_lane"),
    ("The ego vehicle should hold its speed steady and remain in the middle lane.", "keep_speed", "follow_lane"),
    (("The ego vehicle has been moving slowly in heavy traffic, with its speed hovering around 2 m/s and almost no curvature, "
     "which means it has been following its lane in a queue. Since the vehicles in front are now pulling away and the lane ahead "
     "is clear, the ego vehicle should accelerate smoothly to about 6 m/s over the next 3 seconds while staying in its lane."),
     "accelerate", "follow_lane"),
    (("Over the past three seconds the ego vehicle has kept an almost constant speed of roughly 11 m/s with a slight leftward "
     "curvature, consistent with following a gently curving road. Looking ahead, a pedestrian is waiting at the zebra crossing, "
     "so the ego vehicle should reduce its speed noticeably and keep following the curve of its lane."), "decelerate", "follow_lane"),
    (("Recent intent: the vehicle was stationary at the intersection, waiting behind the stop line for the signal to change. "
     "Plan for the next 3 seconds: the signal is still red and there is cross traffic, so the ego vehicle should remain "
     "stationary behind the line until the light changes."), "stay_stopped", U),
    (("The ego vehicle had been decelerating from about 9 m/s to 6 m/s while preparing for the upcoming junction, and its "
     "curvature was close to zero. Because it intends to go left at the junction and there is no oncoming traffic, it "
     "should now make a left turn at a moderate speed of around 5 m/s."), U, "turn_left"),
    (("In the last few seconds the ego vehicle accelerated out of the roundabout and drove straight. Ahead, a parked delivery van "
     "blocks most of the right lane, so over the next three seconds the ego vehicle should change lanes to the left and "
     "maintain its current speed of about 8 m/s."), "keep_speed", "change_lane_left"),
    (("The ego vehicle has been following a lead vehicle at a steady distance, neither accelerating nor braking noticeably. "
     "The lead vehicle's brake lights are now on, and the gap is shrinking; the ego vehicle should brake firmly and come to a "
     "stop behind it, staying in the current lane."), "stop", "follow_lane"),
    (("The ego vehicle was turning right through the intersection during the past 3 seconds, with a curvature of about -0.08. "
     "The turn is almost complete, so the ego vehicle should straighten out, continue straight along the new road and "
     "gradually speed up to the 13 m/s limit."), "accelerate", "follow_lane"),
    (("The ego vehicle is currently traveling at approximately 4.5 m/s and has been decelerating slightly. Given the red "
     "traffic light and the stopped vehicles ahead, the ego vehicle should continue to decelerate smoothly and come to a "
     "complete stop behind the queue, maintaining its lane."), "stop", "follow_lane"),
    (("Based on the history, the ego vehicle has been accelerating moderately (from 2.1 to 4.8 m/s) while going straight. "
     "For the next 3 seconds, it should keep accelerating gently to reach about 7 m/s, staying centered in the current lane."),
     "accelerate", "follow_lane"),
    ("It is recommended that the ego vehicle slows down to around 3 m/s and prepares to stop at the crosswalk.", "decelerate", U),
    ("The ego vehicle should proceed through the intersection, turning right onto the side street.", U, "turn_right"),
    ("The ego car was stationary. It should stay stationary until the light turns green.", "stay_stopped", U),
    ("The ego vehicle should not change lanes and should maintain its current speed.", "keep_speed", U),
    ("I recommend decelerating.", "decelerate", U),
    ("Keep going straight, but slow down a little because of the cyclist.", "decelerate", "follow_lane"),
    # ---- Markdown sections and lists
    (("**Recent intent:** The ego vehicle has been decelerating and following its lane.\n"
     "**Next 3 seconds:** Accelerate gently and keep following the lane."), "accelerate", "follow_lane"),
    ("Recent behavior: decelerating slightly, lane following.\nPlan: come to a stop behind the white car.", "stop", U),
    ("Past: constant speed, straight.\nFuture: turn right at the junction, slowing down.", "decelerate", "turn_right"),
    ("1. Recent intent: accelerating moderately, going straight.\n2. Planned behaviour: maintain speed and stay in lane.", "keep_speed", "follow_lane"),
    ("- History: stopped at a red light\n- Next: start moving when the light turns green", U, U),
    ("Intent: decelerate; lane: keep current lane.", "decelerate", "follow_lane"),
    ("Next 3 seconds: maintain ~8 m/s, follow lane.", "keep_speed", "follow_lane"),
    ("### Past\nThe ego vehicle was turning left.\n### Next 3 s\nThe ego vehicle should finish the turn to the left and accelerate.", "accelerate", "turn_left"),
    ("Action: change lanes to the right and maintain speed.", "keep_speed", "change_lane_right"),
    ("Driving intent: remain stopped.", "stay_stopped", U),
    ("Decision: slow down, keep lane.", "decelerate", "follow_lane"),
    # ---- reasoning blocks
    ("<think>The history shows the car turning left; maybe I should say turn left.</think>The ego vehicle should keep its lane and maintain speed.",
     "keep_speed", "follow_lane"),
    ("<think>Should it stop? The light is red.</think>Stop at the line.", "stop", U),
    # ---- negation
    ("The ego vehicle should not accelerate.", U, U),
    ("Do not change lanes.", U, U),
    ("Do not accelerate; maintain speed and keep the lane.", "keep_speed", "follow_lane"),
    ("There is no need to brake; the ego vehicle should keep its current speed.", "keep_speed", U),
    ("The ego vehicle should avoid turning left here.", U, U),
    ("Don't stop in the intersection.", U, U),
    ("Never speed up near the school zone.", U, U),
    ("The ego vehicle should not turn right.", U, U),
    ("It should slow down rather than accelerate.", "decelerate", U),
    ("Keep the lane without changing lanes, and do not speed up.", U, "follow_lane"),
    # ---- conditionals and hedges
    ("If the light turns green, proceed straight.", U, U),
    ("If the light turns green, accelerate; otherwise stop.", U, U),
    ("Once the pedestrian has crossed, start moving.", U, U),
    ("When the gap opens, merge into the left lane.", U, U),
    ("Be prepared to stop.", U, U),
    ("The ego vehicle may need to slow down.", U, U),
    ("The ego vehicle might turn right at the next intersection.", U, U),
    ("Slow down or stop.", U, U),
    ("Decelerate, and stop if the pedestrian steps onto the road.", "decelerate", U),
    ("Keep following the lane and be ready to brake if the car ahead stops.", U, "follow_lane"),
    ("Accelerate gently unless the car ahead slows.", U, U),
    ("The ego vehicle could possibly change lanes to the right.", U, U),
    ("Perhaps maintain speed.", U, U),
    ("Maintain speed; consider changing lanes to the left if traffic allows.", "keep_speed", U),
    ("Should the light turn red, stop at the line.", U, U),
    ("Stop at the line if the light turns red, and otherwise continue straight.", U, U),
    ("In case the cyclist swerves, slow down.", U, U),
    # ---- contradictions
    ("The ego vehicle should accelerate. The ego vehicle should decelerate.", U, U),
    ("Maintain speed and slow down to 3 m/s.", U, U),
    ("The ego vehicle should turn left and then turn right.", U, U),
    ("Keep straight, then change lanes to the right.", U, U),
    ("Stop, then start moving again.", U, U),
    # ---- other road users
    ("The ego vehicle should keep its lane while the cyclist turns left.", U, "follow_lane"),
    ("The car ahead will turn right, so the ego vehicle should slow down.", "decelerate", U),
    ("Pedestrians may cross; the truck in front is braking. The ego vehicle should maintain a safe distance and keep its lane.", U, "follow_lane"),
    ("The traffic ahead is slowing down. The ego vehicle should slow down too and stay in its lane.", "decelerate", "follow_lane"),
    # ---- stop signs, bus stops and other non-cues
    ("Approach the stop sign slowly and come to a stop.", "stop", U),
    ("Continue past the bus stop at the same speed, keeping the lane.", "keep_speed", "follow_lane"),
    ("The ego vehicle should keep its speed and ignore the slow traffic in the right lane.", "keep_speed", U),
    ("The ego vehicle should turn on the turn signal and maintain speed.", "keep_speed", U),
    # ---- no plan stated
    ("The scene shows a busy urban street with parked cars on both sides.", U, U),
    ("The road is clear.", U, U),
    ("Proceed with caution.", U, U),
    # ---- bad input: never a crash, never a guess
    ("", U, U),
    ("   \n\t ", U, U),
    (("You are driving the ego vehicle; the image is from its front camera. First, describe the ego vehicle's recent intent: "
     "is it accelerating or decelerating? Then, given the scene, say how the ego vehicle should drive over the next 3 seconds. "
     "The ego vehicle should accelerate."), U, U),
    ("El vehículo debe frenar y detenerse en el semáforo, mantener el carril y girar a la izquierda después.", U, U),
    ("Das Fahrzeug sollte langsamer werden und die Spur halten, weil vor uns ein Fußgänger die Straße überquert.", U, U),
    ("自车应减速并保持车道。", U, U),
    ("Should decelerate\x00\x01\x02 and keep lane", U, U),
    ("The ego vehicle should slow down\ufffd and keep lane.", U, U),
    ("<think>The car should stop because", U, U),
    ("The ego vehicle should " + "maintain its speed and keep its lane " * 2000, U, U),
]
# fmt: on
