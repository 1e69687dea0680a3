from setuptools import setup

package_name = 'pkm_gough_sensor'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        'Gough platform metrology: strut lengths, quantization, direct '
        'kinematics, and the sensor node.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'gough_sensor_node = pkm_gough_sensor.gough_sensor_node:main',
            'laser_tracker_node = pkm_gough_sensor.laser_tracker_node:main',
        ],
    },
)
