#!/usr/bin/env python3
"""Check a converted Darknet ONNX model against OpenCV's own Darknet importer.

    python3 tools/check_darknet_onnx.py CFG WEIGHTS MODEL.onnx IMAGE [IMAGE ...]

Needs numpy, pillow, onnxruntime and opencv-python-headless<5 (OpenCV 5 dropped the
Darknet importer). For each image both networks see the same input (RGB / 255, plain
resize to the network size); every prediction OpenCV gives above 0.3 confidence must
have our box within 0.5 px and our objectness x class score within 0.01. Prints the
detections after NMS (threshold 0.3, IoU 0.45) in image pixels, x1,y1,x2,y2.
"""
import sys

import cv2
import numpy as np
import onnxruntime as ort
from PIL import Image


def main():
    if len(sys.argv) < 5:
        raise SystemExit(__doc__)
    cfg, weights, model = sys.argv[1:4]
    session = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    _, _, net_h, net_w = session.get_inputs()[0].shape
    reference = cv2.dnn.readNetFromDarknet(cfg, weights)
    worst_box, worst_score, compared = 0.0, 0.0, 0
    for path in sys.argv[4:]:
        image = Image.open(path).convert("RGB")
        width, height = image.size
        blob = np.asarray(image.resize((net_w, net_h), Image.BILINEAR), np.float32) / 255.0
        blob = blob.transpose(2, 0, 1)[None].copy()
        ours = session.run(None, {"images": blob})[0][0]
        reference.setInput(blob)
        theirs = np.concatenate(reference.forward(reference.getUnconnectedOutLayersNames()), 0)
        # OpenCV: cx, cy, w, h normalised, objectness, objectness x class.
        for row in theirs:
            score = row[5:].max()
            if score < 0.3:
                continue
            box = row[:4] * np.array([net_w, net_h, net_w, net_h])
            scores = ours[:, 4:5] * ours[:, 5:]
            distance = np.abs(ours[:, :4] - box).max(1)
            best = distance.argmin()
            worst_box = max(worst_box, distance[best])
            worst_score = max(worst_score, abs(scores[best].max() - score))
            compared += 1
        print(path)
        for name, score, (x1, y1, x2, y2) in detections(ours, width / net_w, height / net_h):
            print(f"  class {name:2d} {score:.2f} [{x1:.0f},{y1:.0f},{x2:.0f},{y2:.0f}]")
    print(f"{compared} OpenCV predictions compared: largest box difference {worst_box:.4f} px, "
          f"largest score difference {worst_score:.5f}")
    if compared == 0 or worst_box > 0.5 or worst_score > 0.01:
        raise SystemExit("the ONNX model does not match OpenCV's Darknet importer")


def detections(output, sx, sy, threshold=0.3, iou=0.45):
    scores = output[:, 4:5] * output[:, 5:]
    classes, confidences = scores.argmax(1), scores.max(1)
    keep = confidences >= threshold
    boxes = output[keep, :4]
    corners = np.stack([(boxes[:, 0] - boxes[:, 2] / 2) * sx, (boxes[:, 1] - boxes[:, 3] / 2) * sy,
                        (boxes[:, 0] + boxes[:, 2] / 2) * sx, (boxes[:, 1] + boxes[:, 3] / 2) * sy], 1)
    result = []
    for c in np.unique(classes[keep]):
        idx = np.where(classes[keep] == c)[0]
        order = idx[np.argsort(-confidences[keep][idx])]
        while len(order):
            i = order[0]
            result.append((int(c), float(confidences[keep][i]), corners[i]))
            rest = order[1:]
            a, b = corners[i], corners[rest]
            inter = (np.clip(np.minimum(a[2], b[:, 2]) - np.maximum(a[0], b[:, 0]), 0, None)
                     * np.clip(np.minimum(a[3], b[:, 3]) - np.maximum(a[1], b[:, 1]), 0, None))
            union = (a[2] - a[0]) * (a[3] - a[1]) + (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]) - inter
            order = rest[inter / union <= iou]
    return sorted(result, key=lambda r: -r[1])


if __name__ == "__main__":
    main()
